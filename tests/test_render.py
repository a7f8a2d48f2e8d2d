"""The renderer (against sphere tracing in NumPy), camera placement and the sensor model (``jaxpose.render``)."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from jaxpose import render as R
from jaxpose.camera import Intrinsics
from jaxpose.datasets import random_pose
from jaxpose.geometry import matrix_to_rpy, rpy_matrix
from jaxpose.io.skeleton_file import load_skeleton, shipped_skeletons
from jaxpose.kinematics import forward_kinematics
from jaxpose.skeleton import rest_pose

SMALL = Intrinsics(60.0, 60.0, 19.5, 14.5, 40, 30)


# --------------------------------------------------------------------------- independent NumPy oracle


def _sdf_capsule(p, a, b, r):
    ab = b - a
    t = np.clip(((p - a) @ ab) / max(ab @ ab, 1e-12), 0, 1)
    return np.linalg.norm(p - (a + t[..., None] * ab), axis=-1) - r


def _sdf_box(p, c, Rm, h):
    q = np.abs((p - c) @ Rm) - h
    return np.linalg.norm(np.maximum(q, 0), axis=-1) + np.minimum(q.max(-1), 0)


def _march(ray, sdf, t_max=10.0):
    """Sphere tracing of a signed distance function along a unit ray from the origin (NumPy)."""
    t = 0.0
    for _ in range(2000):
        d = sdf(ray * t)
        if d < 1e-6:
            return t
        t += d
        if t > t_max:
            return np.inf
    return t


def test_raycast_matches_sdf_marching():
    rng = np.random.default_rng(0)
    scene = R.Scene(
        cap_start=np.array([[-0.2, -0.1, 1.5], [0.1, 0.2, 2.0], [0.3, -0.2, 1.2]], np.float32),
        cap_end=np.array([[0.2, 0.1, 1.7], [0.1, 0.2, 2.0], [0.1, -0.1, 1.0]], np.float32),  # 2nd: a sphere
        cap_radius=np.array([0.08, 0.15, 0.05], np.float32),
        box_centre=np.array([[-0.3, 0.2, 2.5]], np.float32),
        box_rotation=rpy_matrix(np.array([[0.3, -0.2, 0.7]])).astype(np.float32),
        box_half=np.array([[0.2, 0.1, 0.15]], np.float32),
    )
    depth, ids = R.render_scene(scene, SMALL, with_ids=True)
    rays = np.asarray(R.pixel_rays(SMALL), np.float64)

    def sdf(p):
        d = [_sdf_capsule(p, a, b, r) for a, b, r in zip(scene.cap_start, scene.cap_end, scene.cap_radius)]
        d += [_sdf_box(p, c, Rm, h) for c, Rm, h in zip(scene.box_centre, scene.box_rotation, scene.box_half)]
        return min(d)

    pix = [(v, u) for v in range(SMALL.height) for u in range(SMALL.width)]
    checked_hits = 0
    for idx in rng.choice(len(pix), 250, replace=False):
        v, u = pix[idx]
        t = _march(rays[v, u], sdf)
        if np.isfinite(t):
            checked_hits += 1
            assert depth[v, u] == pytest.approx(t * rays[v, u, 2], abs=2e-4)
            assert ids[v, u] >= 0
        else:
            assert depth[v, u] == 0 and ids[v, u] == -1
    assert checked_hits > 30
    assert set(np.unique(ids)) == {-1, 0, 1, 2, 3}


def test_render_capsules_agrees_with_render_scene():
    skel = load_skeleton("spider")
    pose = R.pose_to_camera(rest_pose(skel), R.orbit_extrinsics((0, 0, 0), 40, 30, 1.0))
    links = forward_kinematics(skel, pose)
    a = np.asarray(R.render_capsules(links.start, links.end, links.radius, SMALL))
    b = R.render_scene(R.capsule_scene(links.start, links.end, links.radius), SMALL)
    np.testing.assert_allclose(a, b, atol=1e-6)
    assert (a > 0).sum() > 20


# --------------------------------------------------------------------------- cameras


def test_matrix_to_rpy_round_trip():
    rng = np.random.default_rng(1)
    for _ in range(200):
        rpy = rng.uniform([-np.pi, -np.pi / 2, -np.pi], [np.pi, np.pi / 2, np.pi])
        Rm = rpy_matrix(rpy)
        np.testing.assert_allclose(rpy_matrix(matrix_to_rpy(Rm)), Rm, atol=1e-9)
    Rm = rpy_matrix(np.array([0.3, np.pi / 2, -0.4]))  # gimbal lock
    np.testing.assert_allclose(rpy_matrix(matrix_to_rpy(Rm)), Rm, atol=1e-9)


@pytest.mark.parametrize("elevation,azimuth", [(0, 0), (30, 75), (60, -140), (89, 10)])
def test_orbit_camera_looks_at_target(elevation, azimuth):
    target = np.array([0.3, -0.2, 0.5])
    T = R.orbit_extrinsics(target, elevation, azimuth, 2.0)
    assert np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-12)
    assert np.linalg.det(T[:3, :3]) == pytest.approx(1.0)
    np.testing.assert_allclose(T[:3, :3] @ target + T[:3, 3], [0, 0, 2.0], atol=1e-12)
    up_cam = T[:3, :3] @ np.array([0, 0, 1.0])
    assert up_cam[1] < 0  # world up is image up (y points down)
    forward_world = T[2, :3]
    assert np.degrees(np.arcsin(-forward_world[2])) == pytest.approx(elevation)


@pytest.mark.parametrize("name", shipped_skeletons())
def test_pose_to_camera_folds_the_transform_into_the_root(name):
    skel = load_skeleton(name)
    pose = random_pose(skel, 3, max_tries=1)
    T = R.orbit_extrinsics((0.1, 0.2, 0.3), 35, 120, 2.5)
    world = forward_kinematics(skel, pose)
    cam = forward_kinematics(skel, R.pose_to_camera(pose, T))
    for a, b in ((world.start, cam.start), (world.end, cam.end)):
        np.testing.assert_allclose(np.asarray(a, np.float64) @ T[:3, :3].T + T[:3, 3], np.asarray(b), atol=2e-5)


# --------------------------------------------------------------------------- sensor model


def _flat(z=2.0, shape=(120, 160)):
    return np.full(shape, z, np.float32)


def test_sensor_is_reproducible_and_seeded():
    d = _flat()
    a = R.apply_sensor(jax.random.PRNGKey(0), d)
    b = R.apply_sensor(jax.random.PRNGKey(0), d)
    c = R.apply_sensor(jax.random.PRNGKey(1), d)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


def test_sensor_off_is_identity_within_range():
    d = _flat()
    d[:10] = 0.0
    d[10:20] = 9.0  # beyond the range
    out = R.apply_sensor(jax.random.PRNGKey(0), d, R.SensorModel.off())
    np.testing.assert_array_equal(out[20:], d[20:])
    assert np.all(out[:20] == 0)


def test_noise_std_follows_kinect_model():
    z = 2.0
    m = R.SensorModel(quantise=False, edges=False, holes=False)
    out = R.apply_sensor(jax.random.PRNGKey(2), _flat(z), m)
    assert np.std(out) == pytest.approx(m.noise_coeff * z**2, rel=0.05)
    assert np.mean(out) == pytest.approx(z, abs=1e-3)


def test_quantisation_follows_disparity_steps():
    m = R.SensorModel(noise=False, edges=False, holes=False)
    z = np.linspace(0.8, 3.9, 160 * 120, dtype=np.float32).reshape(120, 160)
    out = R.apply_sensor(jax.random.PRNGKey(0), z, m)
    n = m.focal_ir * m.baseline / out * m.subpixel  # disparity in 1/8 pixels: an integer
    np.testing.assert_allclose(n, np.round(n), atol=2e-3)
    step = z**2 / (m.focal_ir * m.baseline * m.subpixel)
    assert np.all(np.abs(out - z) <= 0.5 * step * 1.01 + 1e-6)
    assert len(np.unique(out)) < len(np.unique(z)) / 10


def test_missing_pixels_at_edges_and_holes():
    d = _flat(2.0)
    d[40:80, 60:100] = 1.5  # a square in front: a discontinuity along its border
    edges_only = R.SensorModel(noise=False, quantise=False, holes=False, edge_drop=1.0)
    out = R.apply_sensor(jax.random.PRNGKey(0), d, edges_only)
    edge = np.asarray(R.discontinuity_mask(d, edges_only.edge_threshold, 1))
    assert np.all(out[edge] == 0) and np.all(out[~edge] == d[~edge])
    assert edge.sum() == (4 * 40 - 4) + 4 * 40  # the square's border pixels and their outer neighbours
    holes_only = R.SensorModel(noise=False, quantise=False, edges=False, num_holes=5, hole_radius=(3.0, 4.0))
    out = R.apply_sensor(jax.random.PRNGKey(0), _flat(), holes_only)
    missing = (out == 0).sum()
    assert 5 * np.pi * 2.5**2 / 2 < missing <= 5 * np.pi * 4.5**2
