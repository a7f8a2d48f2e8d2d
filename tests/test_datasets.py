"""Random poses, rendered views with their truth, and the two data sets (``jaxpose.datasets``)."""

from __future__ import annotations

import numpy as np
import pytest

from jaxpose import datasets as D
from jaxpose.camera import Intrinsics, foreground_mask
from jaxpose.io.skeleton_file import load_skeleton, shipped_skeletons
from jaxpose.kinematics import forward_kinematics
from jaxpose.render import SensorModel, capsule_scene, render_scene

TINY = Intrinsics(105.0, 105.0, 79.5, 59.5, 160, 120)  # Kinect field of view at 160x120


@pytest.mark.parametrize("name", shipped_skeletons())
def test_random_pose_within_limits_and_seeded(name):
    skel = load_skeleton(name)
    a = D.random_pose(skel, 7, length_spread=0.2, max_tries=3)
    b = D.random_pose(skel, 7, length_spread=0.2, max_tries=3)
    for x, y in zip(a, b):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))
    q = np.asarray(a.angles)
    assert np.all(q >= np.asarray(skel.angle_lo) - 1e-6) and np.all(q <= np.asarray(skel.angle_hi) + 1e-6)
    ln = np.asarray(a.lengths)
    assert np.all(ln >= np.asarray(skel.length_lo) - 1e-6) and np.all(ln <= np.asarray(skel.length_hi) + 1e-6)


def test_floor_and_clutter_are_removed_by_background_subtraction():
    skel = load_skeleton("spider")
    pose = D.random_pose(skel, 0, max_tries=3)
    # edges off: at 160x120 the legs are only a few pixels wide, all of them near an edge
    view = D.render_orbit(skel, pose, 30, 20, 1.2, TINY, floor=True, clutter=3, seed=0,
                          sensor=SensorModel(edges=False))
    assert view.background is not None and (view.background > 0).mean() > 0.3
    clean_subject = render_scene(capsule_scene(view.start, view.end, view.radius), TINY)
    fg = foreground_mask(view.depth, background=view.background)
    subject = clean_subject > 0
    assert (fg & subject).sum() > 0.5 * subject.sum()
    assert (fg & ~subject).sum() < 0.1 * fg.sum()
    # the floor touches the subject's lowest point: no link is below it
    _, _, floor_z = D.subject_frame(skel, pose)
    w = forward_kinematics(skel, pose)
    assert np.all(np.minimum(w.start, w.end)[:, 2] - w.radius >= floor_z - 1e-5)


def test_spider_dataset_is_deterministic_and_seeded():
    skel = load_skeleton("spider")
    kw = dict(k=TINY, num_poses=1, inclinations=(0.0, 60.0), clutter=1)
    a = D.spider_dataset(skel, seed=0, **kw)
    b = D.spider_dataset(skel, seed=0, **kw)
    c = D.spider_dataset(skel, seed=1, **kw)
    assert [s.name for s in a] == ["pose0_incl00", "pose0_incl60"]
    np.testing.assert_array_equal(a[1].view.depth, b[1].view.depth)
    assert not np.allclose(a[1].view.end, c[1].view.end)
    # one pose, two inclinations: the same pose in the world frame
    np.testing.assert_array_equal(np.asarray(a[0].view.pose_world.angles), np.asarray(a[1].view.pose_world.angles))


def test_humanoid_dataset_subjects_differ_symmetrically():
    skel = load_skeleton("humanoid")
    ds = D.humanoid_dataset(skel, seed=0, k=TINY, num_subjects=2, poses_per_subject=1, clutter=0, floor=False,
                            sensor=None)
    l0, l1 = (np.asarray(s.view.pose.lengths) for s in ds)
    assert not np.allclose(l0, l1)
    i, j = skel.index("l_thigh"), skel.index("r_thigh")
    assert l0[i] == l0[j]
    assert float(ds[0].view.pose.scale) != float(ds[1].view.pose.scale)
