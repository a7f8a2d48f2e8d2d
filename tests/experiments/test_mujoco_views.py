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

import mujoco_views as MV
import numpy as np
import pytest

pytest.importorskip("mujoco")
_PROBLEM = MV.gl_problem()
pytestmark = pytest.mark.skipif(_PROBLEM is not None, reason=str(_PROBLEM))

FIXTURES = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "fixtures")


def _seg_distance(P, a, b):
    ab = b - a
    t = np.clip(((P - a) @ ab) / max(float(ab @ ab), 1e-12), 0.0, 1.0)
    return np.linalg.norm(P - (a + t[:, None] * ab), axis=1)


def surface_distances(name, view_seed, size=(200, 150), max_capsules=None):
    """Signed distances (m) from every model pixel MuJoCo renders to jaxpose's nearest capsule surface
    (the model loaded with ``max_capsules`` capsules per link; ``None``: the default)."""
    import mujoco

    from jaxpose.kinematics import forward_kinematics

    m, skel, to_pose = MV.load(os.path.join(FIXTURES, name), max_capsules)
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
    return np.min([_seg_distance(P, s[i], e[i]) - rad[i] for i in range(skel.num_links) if rad[i] > 0], axis=0)


@pytest.mark.parametrize("seed", [0, 1])
def test_capsule_model_pixels_lie_on_jaxpose_capsules(seed):
    """The ant is made of capsules and a sphere: MuJoCo's pixels lie on jaxpose's surfaces."""
    dist = surface_distances("ant.xml", seed)
    assert len(dist) > 500
    assert np.median(np.abs(dist)) < 2e-3 and np.percentile(np.abs(dist), 99) < 1e-2


def test_boxes_and_cylinders_lie_inside_their_enclosing_capsules():
    """With one capsule per link, the gripper's boxes and cylinders (prismatic joints moved) lie
    inside jaxpose's capsules."""
    dist = surface_distances("gripper.urdf", 2, max_capsules=1)
    assert len(dist) > 300
    assert np.percentile(dist, 99) < 2e-3  # inside or on the surface (up to the depth buffer's precision)
    assert np.median(dist) < -1e-3  # and mostly strictly inside: the capsules enclose, not fit, these shapes


@pytest.mark.parametrize("name, seed, ratio", [("gripper.urdf", 1, 0.75), ("gadget.xml", 1, 0.75),
                                               ("quadruped.urdf", 2, 0.5)])
def test_several_capsules_per_link_lie_closer_to_what_mujoco_draws(name, seed, ratio):
    """The default model (a capsule per geometry, plates and disks cut into slabs) puts its surfaces
    closer to the pixels MuJoCo draws of the true geometry than one enclosing capsule per link
    (mean distance; measured 0.58, 0.61 and 0.31 of it)."""
    one = np.abs(surface_distances(name, seed, max_capsules=1))
    default = np.abs(surface_distances(name, seed))
    assert len(default) == len(one) > 300  # the same pixels
    assert np.mean(default) < ratio * np.mean(one)


def test_frames_score_counts_links_whose_frame_is_placed_right():
    """frames@5cm against hand-made truths: itself 1; one link turned a quarter round 5/6 (the
    gripper's extra capsule shares the turntable's frame and is left out); every origin 6 cm off 0."""
    from jaxpose.io.skeleton_file import load_skeleton
    from jaxpose.kinematics import forward_kinematics
    from jaxpose.skeleton import rest_pose

    skel = load_skeleton(os.path.join(FIXTURES, "gripper.urdf"))
    assert skel.num_links == 7 and sum(b != i for i, b in enumerate(skel.bodies)) == 1
    links = forward_kinematics(skel, rest_pose(skel))
    R, o = np.asarray(links.R_world_link, np.float64), np.asarray(links.origin, np.float64)
    assert MV.frames_score(skel, links, R, o) == 1.0
    turned = R.copy()
    c = skel.index("column")
    turned[c] = R[c] @ np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    assert MV.frames_score(skel, links, turned, o) == pytest.approx(5 / 6)
    assert MV.frames_score(skel, links, R, o + np.array([0.0, 0.06, 0.0])) == 0.0
    assert MV.frames_score(skel, links, R, o + np.array([0.0, 0.04, 0.0])) == 1.0  # within 5 cm


def test_spread_argument_and_public_models():
    import argparse

    assert MV.spread_arg("uniform") is None and MV.spread_arg("0.5") == 0.5
    for bad in ("0", "-1", "wide"):
        with pytest.raises(argparse.ArgumentTypeError):
            MV.spread_arg(bad)
    assert MV.public_model("tests/fixtures/ant.xml") == "tests/fixtures/ant.xml"
    with pytest.raises(ValueError, match="gymnasium"):
        MV.public_model("gymnasium:no_such_model.xml")


def test_summary_counts_whole_body_misses_and_splits_seen_links_and_verdicts():
    base = {"model": "m", "file": "m.xml", "links": 3, "pcp_links": 3, "pcp_10cm": 1.0, "pck_10cm": 1.0,
            "frames_5cm": 1.0, "mpjpe_mm": 5.0, "seconds": 1.0}
    views = [  # (pcp, seen links, seen placed, hidden links, hidden placed, verdict)
        (1.0, 3, 3, 0, 0, None), (0.2, 2, 0, 1, 1, "search"), (0.0, 2, 0, 1, 0, "objective"),
        (0.25, 3, 1, 0, 0, "search"), (None, 0, 0, 0, 0, None)]
    rows = MV.summary([{**base, "pcp": p, "seen_links": s, "seen_placed": sp, "hidden_links": h,
                        "hidden_placed": hp, "verdict": v} for p, s, sp, h, hp, v in views])
    r = rows[0]
    assert r["whole_body_misses"] == 2 and r["views"] == 5
    assert r["seen_links"] == 10 and r["seen_pcp"] == pytest.approx(4 / 10)
    assert r["hidden_links"] == 2 and r["hidden_pcp"] == pytest.approx(1 / 2)
    assert r["missed_views"] == {"search": 2, "objective": 1}
    assert r["whole_body_verdicts"] == {"search": 1, "objective": 1}  # the 0.25 view is no whole-body miss
    table = MV.markdown(rows, "test machine")
    assert "| 40.0% (10) | 50.0% (2) | 2 (1 / 1) | 2 / 1 |" in table


def test_set_names_a_bad_setting_in_one_line_and_needs_its_own_folder(tmp_path, capsys):
    with pytest.raises(SystemExit, match="turns must be 0-3"):
        MV.main(["--set", "turns=9", "--out", str(tmp_path)])
    with pytest.raises(SystemExit) as e:
        MV.main(["--set", "turns=1"])
    assert e.value.code == 2 and "--set needs --out" in capsys.readouterr().err
    assert list(tmp_path.iterdir()) == []  # nothing written


def test_a_view_weighs_the_found_pose_with_the_fits_own_cost_and_counts_seen_links(tmp_path):
    """The found pose scored again on the fit's cloud (pose_costs) must give the fit's own cost, the
    verdict follow from the two costs, and every scored link be seen or hidden."""
    from common import miss_verdict

    from jaxpose.search import FitConfig

    config = FitConfig(population=8, generations=2, limb_sweep=0, pivot_sweep=0, turns=0)
    (rec,) = MV.run_model(os.path.join(FIXTURES, "planar.xml"), 1, 0, 0.3, config, str(tmp_path), size=(160, 120),
                          plots=0)
    assert rec["found_cost"] == pytest.approx(rec["cost"], abs=1e-5)
    assert rec["truth_cost"] >= 0 and all(0.0 <= v <= 1.0 for v in rec["visible"])
    assert rec["seen_links"] + rec["hidden_links"] == sum(rec["scored"]) and rec["seen_links"] > 0
    placed = round(rec["pcp"] * sum(rec["scored"]))
    assert rec["seen_placed"] + rec["hidden_placed"] == placed
    expected = None if placed == sum(rec["scored"]) else miss_verdict(rec["found_cost"], rec["truth_cost"])
    assert rec["verdict"] == expected


def test_a_drawn_pose_keeps_the_robots_own_geoms_apart():
    """arm7's uniform draw of view (1, 19) folds the arm into itself (MuJoCo's contacts, over 10 cm
    deep): it is drawn again until MuJoCo's own contacts, recomputed here, stay within the limit;
    the forearm and wrist, which touch in the rest pose, are not counted."""
    import mujoco

    m, _, _ = MV.load(os.path.join(FIXTURES, "arm7.urdf"))
    ignore = MV.rest_contacts(m)
    names = {tuple(sorted(m.body(m.geom_bodyid[g]).name for g in pair)) for pair in ignore}
    assert names == {("forearm_link", "wrist2_link")}
    d = mujoco.MjData(m)
    d.qpos[:] = MV.random_qpos(m, np.random.default_rng([1, 19]), None, root_joints=False)
    assert MV.self_contact_depth(m, d, ignore) > 0.1
    q, depth, draws = MV.draw_qpos(m, d, np.random.default_rng([1, 19]), None, root_joints=False, ignore=ignore)
    assert draws > 1 and depth <= MV.MAX_INTERPENETRATION and np.array_equal(d.qpos, q)
    fresh = mujoco.MjData(m)
    fresh.qpos[:] = q
    mujoco.mj_forward(m, fresh)
    own = [c for c in fresh.contact[: fresh.ncon] if (c.geom1, c.geom2) not in ignore
           and m.geom_bodyid[c.geom1] > 0 and m.geom_bodyid[c.geom2] > 0]
    assert sum(max(0.0, -c.dist) for c in own) == pytest.approx(depth)
    # one draw allowed: the first pose is kept, whatever it is
    q1, depth1, draws1 = MV.draw_qpos(m, d, np.random.default_rng([1, 19]), None, root_joints=False, max_tries=1,
                                      ignore=ignore)
    assert draws1 == 1 and depth1 > 0.1


def test_drawn_joint_values_lie_in_the_skeletons_ranges():
    """Uniform draws stay within what the importer lets the fit express: the planar walker's
    unlimited slide ('rail') included, whose range is the model's size."""
    import mujoco

    m, skel, to_pose = MV.load(os.path.join(FIXTURES, "planar.xml"))
    d = mujoco.MjData(m)
    lo, hi = np.asarray(skel.angle_lo, np.float64), np.asarray(skel.angle_hi, np.float64)
    rng = np.random.default_rng(3)
    for _ in range(50):
        d.qpos[:] = MV.random_qpos(m, rng, None)
        angles = np.asarray(to_pose(d.qpos).angles, np.float64)
        assert np.all(angles >= lo - 1e-5) and np.all(angles <= hi + 1e-5)
    rail = m.joint("rail").id
    assert MV.joint_span(m, rail)[1] == pytest.approx(float(hi[skel.index("tail"), 0]), rel=1e-6)
