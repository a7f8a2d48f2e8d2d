"""Depth image -> point cloud (``jaxpose.camera``) against the pinhole formula in NumPy.

Convention (``jaxpose/camera.py``): pixel ``(u, v)`` is column ``u``, row ``v``, with
its centre at the integer coordinates (so the Kinect's ``cx = 319.5`` is the middle
of a 640-pixel row); ``x = (u - cx) z / fx``, ``y = (v - cy) z / fy``, ``z = depth``.
"""

from __future__ import annotations

import numpy as np
import pytest

from jaxpose.camera import KINECT_V1, Intrinsics, depth_to_cloud, depth_to_points, foreground_mask, off_planes
from jaxpose.errors import DepthError

# non-square focal lengths and an off-centre principal point, so swapped axes show
K = Intrinsics(fx=50.0, fy=65.0, cx=6.25, cy=4.75, width=16, height=12)


def backproject(depth, k, rows, cols):
    """The oracle: camera-frame points of pixels (row v, column u), float64."""
    z = np.asarray(depth, np.float64)[rows, cols]
    u = np.asarray(cols, np.float64)
    v = np.asarray(rows, np.float64)
    return np.stack([(u - k.cx) * z / k.fx, (v - k.cy) * z / k.fy, z], -1)


def sorted_rows(a):
    a = np.asarray(a, np.float64)
    return a[np.lexsort(a.T[::-1])]


def kept_points(cloud):
    w = np.asarray(cloud.weights)
    return np.asarray(cloud.points, np.float64)[w > 0]


def test_depth_to_points_is_the_pinhole_formula():
    rng = np.random.default_rng(0)
    depth = rng.uniform(0.4, 5.0, (K.height, K.width))
    depth[0, 0] = 0.0
    depth[3, 7] = np.nan
    depth[11, 15] = np.inf
    depth[5, 2] = -1.0
    pts, valid = depth_to_points(depth, K)
    assert pts.shape == (K.height * K.width, 3) and valid.shape == (K.height * K.width,)
    expect_valid = np.isfinite(depth) & (depth > 0)
    np.testing.assert_array_equal(valid, expect_valid.reshape(-1))
    rows, cols = np.nonzero(expect_valid)
    got = pts.reshape(K.height, K.width, 3)[rows, cols]
    np.testing.assert_allclose(got, backproject(depth, K, rows, cols), rtol=1e-12, atol=1e-12)
    # the principal point itself would project to x = y = 0: pixel (6, 4) lies 0.25 px left, 0.75 px up
    assert got[(rows == 4) & (cols == 6)][0, 0] < 0 and got[(rows == 4) & (cols == 6)][0, 1] < 0


def test_cloud_points_are_the_backprojected_pixels():
    depth = np.zeros((K.height, K.width))
    depth[2:8, 3:12] = np.linspace(1.0, 2.5, 6 * 9).reshape(6, 9)
    cloud = depth_to_cloud(depth, K, near=0.3, far=8.0, max_points=100, min_points=1)
    assert np.asarray(cloud.points).shape == (100, 3) and np.asarray(cloud.weights).shape == (100,)
    w = np.asarray(cloud.weights)
    assert set(np.unique(w)) == {0.0, 1.0} and int(w.sum()) == 54  # padded with weight-0 points
    rows, cols = np.nonzero(depth > 0)
    np.testing.assert_allclose(sorted_rows(kept_points(cloud)), sorted_rows(backproject(depth, K, rows, cols)),
                               rtol=1e-6, atol=1e-6)


def test_depths_outside_near_far_are_dropped():
    near, far = 0.5, 3.0
    depth = np.zeros((K.height, K.width))
    depth[0:4, 0:5] = 0.3  # too near
    depth[0:4, 8:14] = 4.5  # too far
    depth[6:10, 0:5] = 1.2  # kept
    depth[6:10, 8:14] = far  # the far end itself is kept ([near, far] is closed)
    cloud = depth_to_cloud(depth, K, near=near, far=far, max_points=200, min_points=1)
    keep = (depth >= near) & (depth <= far)
    rows, cols = np.nonzero(keep)
    assert len(rows) == 4 * 5 + 4 * 6
    np.testing.assert_allclose(sorted_rows(kept_points(cloud)), sorted_rows(backproject(depth, K, rows, cols)),
                               rtol=1e-6, atol=1e-6)
    z = kept_points(cloud)[:, 2]
    assert z.min() >= near - 1e-6 and z.max() <= far + 1e-6


def test_nothing_within_near_far_is_an_error():
    depth = np.full((K.height, K.width), 9.0)
    with pytest.raises(DepthError):
        depth_to_cloud(depth, K, near=0.3, far=8.0, min_points=1)


def _big_scene():
    k = Intrinsics(100.0, 100.0, 19.5, 14.5, 40, 30)
    rng = np.random.default_rng(1)
    depth = np.zeros((30, 40))
    depth[5:25, 10:30] = rng.uniform(1.0, 2.0, (20, 20))  # 400 pixels
    return depth, k


def test_subsample_is_seeded():
    depth, k = _big_scene()
    rows, cols = np.nonzero(depth > 0)
    all_pts = backproject(depth, k, rows, cols)
    a = depth_to_cloud(depth, k, max_points=50, seed=3, min_points=1)
    b = depth_to_cloud(depth, k, max_points=50, seed=3, min_points=1)
    c = depth_to_cloud(depth, k, max_points=50, seed=4, min_points=1)
    np.testing.assert_array_equal(np.asarray(a.points), np.asarray(b.points))
    np.testing.assert_array_equal(np.asarray(a.weights), np.asarray(b.weights))
    pa, pc = kept_points(a), kept_points(c)
    assert len(pa) == len(pc) == 50  # more pixels than max_points: no padding
    assert {tuple(p) for p in np.round(pa, 5)} != {tuple(p) for p in np.round(pc, 5)}
    for p in (pa, pc):  # a subset of the image's points, without repeats
        d = np.linalg.norm(p[:, None, :] - all_pts[None], axis=-1)
        assert np.all(d.min(1) < 1e-5)
        assert len(set(d.argmin(1))) == 50


def test_background_subtraction():
    """Keep pixels more than ``0.05 + 0.0045 b**2`` m in front of the background ``b`` (README)."""
    b = 2.0
    tol = 0.05 + 0.0045 * b**2  # 0.068 m
    background = np.full((K.height, K.width), b)
    background[8:12, 12:16] = 0.0  # the background has no measurement there: kept
    depth = np.zeros((K.height, K.width))
    depth[0:4, 0:4] = b - 0.5  # clearly in front: kept
    depth[0:4, 6:10] = b - 0.03  # within 5 cm: dropped
    depth[0:4, 12:16] = b - 0.06  # beyond 5 cm but within the depth-dependent noise term: dropped
    depth[6:10, 0:4] = b - 0.09  # beyond the whole tolerance: kept
    depth[6:10, 6:10] = b + 0.2  # behind the background: dropped
    depth[8:12, 12:16] = 1.7  # no background measurement: kept
    cloud = depth_to_cloud(depth, K, near=0.3, far=8.0, background=background, max_points=200, min_points=1)
    valid_bg = background > 0
    keep = (depth > 0) & (~valid_bg | (depth < background - tol))
    rows, cols = np.nonzero(keep)
    assert len(rows) == 3 * 16
    np.testing.assert_allclose(sorted_rows(kept_points(cloud)), sorted_rows(backproject(depth, K, rows, cols)),
                               rtol=1e-6, atol=1e-6)
    # without the background every pixel with depth stays
    full = depth_to_cloud(depth, K, near=0.3, far=8.0, max_points=200, min_points=1)
    assert int(np.asarray(full.weights).sum()) == int((depth > 0).sum())


def test_off_planes_removes_a_floor_and_a_wall_and_keeps_the_subject():
    """A noisy floor and wall (planes written down directly) and a ball in front:
    one plane removed takes the larger (the floor), two take both; the ball stays,
    and a third plane is not cut through it."""
    rng = np.random.default_rng(5)
    u, v = rng.uniform(-1.5, 1.5, (2, 20000))
    floor = np.stack([u, 0.9 + 0.005 * rng.normal(size=u.size), 2.5 + v], -1)  # y = 0.9 (y points down)
    a, b = rng.uniform(-1.5, 1.5, (2, 8000))
    wall = np.stack([a, b * 0.5, 4.0 + 0.01 * rng.normal(size=a.size)], -1)  # z = 4
    d = rng.normal(size=(3000, 3))
    ball = 0.25 * d / np.linalg.norm(d, axis=1, keepdims=True) + [0.1, 0.3, 2.2]
    pts = np.concatenate([floor, wall, ball])
    kind = np.repeat([0, 1, 2], [len(floor), len(wall), len(ball)])
    one, two, three = (off_planes(pts, n, seed=3) for n in (1, 2, 3))
    assert one[kind == 0].mean() < 0.01 and one[kind == 1].mean() > 0.95 and one[kind == 2].mean() > 0.97
    assert two[kind == 1].mean() < 0.01 and two[kind == 2].mean() > 0.97
    assert np.array_equal(three, two)  # the ball is no plane
    assert np.array_equal(off_planes(pts, 2, seed=3), two)  # deterministic
    assert off_planes(ball, 1).all()


def test_plane_removal_keeps_what_background_subtraction_keeps(tmp_path):
    """A rendered spider on a floor: the points left after removing one plane are,
    nearly all, the points that subtracting the rendered background image leaves
    (an independent way to find the subject)."""
    import jaxpose.cli as cli
    from jaxpose.io.depth_file import load_depth

    assert cli.main(["render", "--skeleton", "spider", "--seed", "2", "--elevation", "30", "--floor", "--no-noise",
                     "--size", "320x240", "--out", str(tmp_path / "d.png"), "--truth", str(tmp_path / "t.json"),
                     "--background-out", str(tmp_path / "b.png")]) == 0
    k = KINECT_V1._replace(fx=262.5, fy=262.5, cx=159.5, cy=119.5, width=320, height=240)
    depth, background = load_depth(tmp_path / "d.png"), load_depth(tmp_path / "b.png")
    pts, _ = depth_to_points(depth, k)
    subject = foreground_mask(depth, 0.3, 8.0, background).reshape(-1)
    scene = np.flatnonzero(foreground_mask(depth, 0.3, 8.0).reshape(-1))
    kept = scene[off_planes(pts[scene], 1)]
    assert subject.sum() > 500 and len(scene) > 10 * subject.sum()
    assert subject[kept].mean() > 0.95  # what is left is the subject
    assert np.isin(np.flatnonzero(subject), kept).mean() > 0.9  # and most of the subject is left
    for seed in range(6):  # asking for more planes than the scene has does not cut into the spider
        assert np.array_equal(off_planes(pts[scene], 3, seed=seed), off_planes(pts[scene], 1, seed=seed)), seed
    # a depth image and its foreground written as points give the same cloud with a plane removed
    from jaxpose.camera import sensor_points_to_cloud

    a = depth_to_cloud(depth, k, max_points=1024, seed=3, remove_planes=2)
    b = sensor_points_to_cloud(pts[scene].astype(np.float32), max_points=1024, seed=3, remove_planes=2)
    assert np.array_equal(a.points, b.points) and np.array_equal(a.weights, b.weights)
    with pytest.raises(DepthError, match="remove_planes must be an integer"):
        depth_to_cloud(depth, k, remove_planes=-1)
    with pytest.raises(DepthError, match="plane_tolerance"):
        sensor_points_to_cloud(pts[scene], plane_tolerance=float("nan"), remove_planes=1)


def test_scale_warning_catches_a_cloud_in_the_wrong_unit():
    """The bundled spider image, in metres, needs no warning; the same points read in
    tenths (10x) or millimetres read as metres would be fitted at the edge of the
    skeleton's scale range, and the warning says so."""
    import os

    from jaxpose.demo import DATA
    from jaxpose.io.skeleton_file import load_skeleton
    from jaxpose.objective import Cloud
    from jaxpose.pipeline import InputOptions, load_observation, scale_warning

    skel = load_skeleton("spider")
    image, background = (os.path.join(DATA, f"spider_demo{s}.png") for s in ("", "_background"))
    _, _, cloud = load_observation(image, InputOptions(background=background))
    assert scale_warning(skel, cloud, "demo.png") is None
    for factor in (10.0, 1 / 10):
        big = Cloud(cloud.points * factor, cloud.weights)
        msg = scale_warning(skel, big, "demo.png")
        assert msg.startswith("demo.png: the points spread") and "scale range 0.5 .. 2" in msg and "unit" in msg
    assert scale_warning(skel, Cloud(cloud.points * 1.8, cloud.weights), "demo.png") is None  # a big spider


def test_scale_warning_leaves_a_held_scale_room_for_the_pose():
    """A held scale (a robot file's, scale range one value) has no range to absorb a folded
    pose's short spread: 0.6 or 1.6 times the spread at that scale passes, a unit off by 5 does not."""
    import dataclasses
    import os

    import jax.numpy as jnp

    from jaxpose.demo import DATA
    from jaxpose.io.skeleton_file import load_skeleton
    from jaxpose.objective import Cloud
    from jaxpose.objective.cloud import cloud_spread
    from jaxpose.pipeline import InputOptions, load_observation, scale_warning
    from jaxpose.rest_model import rest_model

    skel = load_skeleton("spider")
    image, background = (os.path.join(DATA, f"spider_demo{s}.png") for s in ("", "_background"))
    _, _, cloud = load_observation(image, InputOptions(background=background))
    s = jnp.float32(cloud_spread(cloud) / rest_model(skel).spread)  # the cloud's own size, held
    held = dataclasses.replace(skel, scale_lo=s, scale_hi=s)
    for factor, warned in ((0.6, False), (1.6, False), (5.0, True), (0.2, True)):
        got = scale_warning(held, Cloud(cloud.points * factor, cloud.weights), "demo.png")
        assert (got is not None) == warned, (factor, got)
