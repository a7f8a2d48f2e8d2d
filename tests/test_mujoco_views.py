"""MuJoCo's own renderer against jaxpose's kinematics and capsules (experiments/mujoco_views.py).

MuJoCo draws the models' true geoms with OpenGL; every pixel it shows of a model must lie
on (capsule geoms) or inside (boxes, cylinders: enclosed) the capsules jaxpose poses from
the same joint values, seen through the camera frame and intrinsics the experiment derives.
This checks the experiment's conventions (pixel centres, rows, the camera's frame, depth
along the optical axis) and the importers (``pose_from_qpos``, URDF prismatic joints)
with a renderer jaxpose did not write.  Skipped where MuJoCo has no OpenGL context.
"""

from __future__ import annotations

import os
import sys

import numpy as np
import pytest

sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "experiments"))
import mujoco_views as MV  # noqa: E402

pytest.importorskip("mujoco")
_PROBLEM = MV.gl_problem()
pytestmark = pytest.mark.skipif(_PROBLEM is not None, reason=str(_PROBLEM))

FIXTURES = os.path.join(os.path.dirname(os.path.abspath(__file__)), "fixtures")


def _seg_distance(P, a, b):
    ab = b - a
    t = np.clip(((P - a) @ ab) / max(float(ab @ ab), 1e-12), 0.0, 1.0)
    return np.linalg.norm(P - (a + t[:, None] * ab), axis=1)


def surface_distances(name, view_seed, size=(200, 150)):
    """Signed distances (m) from every model pixel MuJoCo renders to jaxpose's nearest capsule surface,
    and the name of that capsule's link."""
    import mujoco

    from jaxpose.kinematics import forward_kinematics

    m, skel, to_pose = MV.load(os.path.join(FIXTURES, name))
    d = mujoco.MjData(m)
    rng = np.random.default_rng(view_seed)
    d.qpos[:] = MV.random_qpos(m, rng, 0.3, root_joints=not name.endswith(".urdf"))
    mujoco.mj_kinematics(m, d)
    cam, k = MV.camera_view(m, d, rng, *size)
    r = mujoco.Renderer(m, size[1], size[0])
    r.enable_depth_rendering()
    try:
        depth, centre, R = MV.render_depth(r, m, d, cam)
        background, _, _ = MV.render_depth(r, m, d, cam, hide_model=True)
    finally:
        r.close()
    model = np.isfinite(depth) & ~(np.nan_to_num(background, nan=np.inf) - depth < 1e-3)
    v, u = np.nonzero(model)
    z = depth[v, u]
    P = np.stack([(u - k.cx) * z / k.fx, (v - k.cy) * z / k.fy, z], -1)
    links = forward_kinematics(skel, to_pose(d.qpos))
    s = (np.asarray(links.start, np.float64) - centre) @ R.T
    e = (np.asarray(links.end, np.float64) - centre) @ R.T
    rad = np.asarray(links.radius, np.float64)
    shown = [i for i in range(skel.num_links) if rad[i] > 0]
    D = np.array([_seg_distance(P, s[i], e[i]) - rad[i] for i in shown])
    return D.min(0), np.array([skel.link_names[shown[k]] for k in D.argmin(0)])


@pytest.mark.parametrize("seed", [0, 1])
def test_capsule_model_pixels_lie_on_jaxpose_capsules(seed):
    """The ant is made of capsules and a sphere: MuJoCo's pixels lie on jaxpose's surfaces."""
    dist, _ = surface_distances("ant.xml", seed)
    assert len(dist) > 500
    assert np.median(np.abs(dist)) < 2e-3 and np.percentile(np.abs(dist), 99) < 1e-2


def test_cylinders_lie_inside_their_capsules_and_a_box_about_its_fitted_one():
    """The gripper (prismatic joints moved): its cylinders lie inside their enclosing capsules;
    its column, a box alone, has the capsule fitted to its faces, which it straddles."""
    dist, link = surface_distances("gripper.urdf", 2)
    assert len(dist) > 300 and np.percentile(dist, 99) < 0.01  # on or near a capsule everywhere
    table = dist[link == "turntable"]  # a flat cylinder: strictly inside its enclosing capsule
    assert len(table) > 30 and np.percentile(table, 90) < 2e-3 and np.median(table) < -0.01
    box = dist[link == "column"]  # a box alone: its capsule is fitted, some pixels in, some out
    assert len(box) > 50 and np.median(np.abs(box)) < 0.01 and box.min() < -2e-3 and box.max() > 2e-3
