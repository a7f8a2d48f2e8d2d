"""MJCF importer: mapping, geometry, forward kinematics against MuJoCo, bad files."""

from __future__ import annotations

import os
import sys

import jax
import numpy as np
import pytest

from jaxpose.errors import SkeletonError
from jaxpose.geometry import quat_to_matrix
from jaxpose.io.skeleton_file import load_skeleton
from jaxpose.kinematics import forward_kinematics
from jaxpose.genome import genome_layout

mujoco = pytest.importorskip("mujoco")
from jaxpose.io.mjcf import compile_mjcf, load_mjcf, pose_from_qpos, skeleton_from_model  # noqa: E402

FIXTURES = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "fixtures")
FK_TOL = 1e-5  # metres (positions) and matrix entries (rotations); jaxpose runs in float32
MODELS = ["ant", "humanoid_lite", "gadget", "planar", "reacher_like"]


def fixture(name):
    return os.path.join(FIXTURES, f"{name}.xml")


_cache = {}


def model_and_skeleton(name):
    if name not in _cache:
        m = compile_mjcf(fixture(name))
        # one capsule per body: these tests check the enclosing capsules (tests/io/test_capsules.py: several)
        _cache[name] = (m, skeleton_from_model(m, source=fixture(name), max_capsules=1))
    return _cache[name]


def body_name(m, b):
    return m.body(b).name or f"body{b}"


def posed_at_random(m, skel, rng):
    """MuJoCo's kinematics and jaxpose's links (a batch of one) at one :func:`random_qpos`."""
    d = mujoco.MjData(m)
    q = random_qpos(m, rng)
    d.qpos[:] = q
    mujoco.mj_kinematics(m, d)
    return d, batched_fk(skel, [pose_from_qpos(skel, m, q)])


def random_qpos(m, rng):
    q = m.qpos0.copy()
    for j in range(m.njnt):
        a, t = m.jnt_qposadr[j], m.jnt_type[j]
        if t == mujoco.mjtJoint.mjJNT_FREE:
            q[a : a + 3] = rng.uniform(-1, 1, 3)
            v = rng.normal(size=4)
            q[a + 3 : a + 7] = v / np.linalg.norm(v)
        elif t == mujoco.mjtJoint.mjJNT_BALL:
            v = rng.normal(size=4)
            q[a : a + 4] = v / np.linalg.norm(v)
        elif t == mujoco.mjtJoint.mjJNT_HINGE:
            lo, hi = m.jnt_range[j] if m.jnt_limited[j] else (-np.pi, np.pi)
            q[a] = rng.uniform(lo, hi)
        elif t == mujoco.mjtJoint.mjJNT_SLIDE:
            q[a] = rng.uniform(*m.jnt_range[j]) if m.jnt_limited[j] else rng.uniform(-1, 1)
    return q


def batched_fk(skel, poses):
    stacked = jax.tree.map(lambda *a: np.stack(a), *poses)
    return jax.jit(jax.vmap(forward_kinematics, in_axes=(None, 0)))(skel, stacked)


# --------------------------------------------------------------------------- mapping


def test_ant_links_and_joints():
    skel = load_skeleton(fixture("ant"))  # through the dispatcher
    assert skel.name == "ant"
    assert skel.link_names[0] == "torso" and skel.parents[0] == -1
    assert skel.joint_types[skel.index("torso")] == "fixed"  # the free joint is the root pose
    assert {"front_left_leg", "aux_1", "aux_4", "body4", "body13"} <= set(skel.link_names)  # unnamed -> body<id>
    assert skel.joint_types.count("hinge") == 8
    assert skel.num_dof == 7 + 8
    i = skel.index("aux_1")
    np.testing.assert_allclose(np.rad2deg(skel.angle_lo[i, 0]), -30, atol=1e-4)
    np.testing.assert_allclose(np.rad2deg(skel.angle_hi[i, 0]), 30, atol=1e-4)
    np.testing.assert_allclose(skel.axis[i], [0, 0, 1], atol=1e-6)
    assert np.all(np.asarray(skel.attach) == 0)
    assert np.all(np.asarray(skel.length_lo) == np.asarray(skel.length_hi))  # fixed by default


def test_humanoid_multi_hinge_bodies_become_chains():
    _, skel = model_and_skeleton("humanoid_lite")
    for extra in ["right_thigh/right_hip_x", "right_thigh/right_hip_z", "lwaist/abdomen_z", "lwaist/abdomen_y",
                  "right_upper_arm/right_shoulder1", "right_shin/right_knee", "pelvis/abdomen_x"]:
        i = skel.index(extra)
        assert skel.joint_types[i] == "hinge"
        assert float(skel.length[i]) == 0 and float(skel.radius[i]) == 0
    # the chain: hip_x -> hip_z -> right_thigh (carries hip_y and the geometry)
    thigh = skel.index("right_thigh")
    assert skel.link_names[skel.parents[thigh]] == "right_thigh/right_hip_z"
    assert skel.link_names[skel.parents[skel.index("right_thigh/right_hip_z")]] == "right_thigh/right_hip_x"
    assert skel.link_names[skel.parents[skel.index("right_thigh/right_hip_x")]] == "pelvis"
    assert skel.joint_types[thigh] == "hinge" and float(skel.radius[thigh]) == pytest.approx(0.06)
    np.testing.assert_allclose(np.rad2deg([skel.angle_lo[thigh, 0], skel.angle_hi[thigh, 0]]), [-120, 20], atol=1e-4)
    # a joint anchored off the body origin: the body link is fixed, back at the body origin
    assert skel.joint_types[skel.index("lwaist")] == "fixed"
    assert skel.joint_types[skel.index("right_shin")] == "fixed"
    # 17 hinges + root
    assert skel.joint_types.count("hinge") == 17 and skel.num_dof == 7 + 17


def test_gadget_ball_ref_and_world_attached_base():
    m, skel = model_and_skeleton("gadget")
    assert skel.parents[skel.index("base")] == -1 and skel.joint_types[skel.index("base")] == "fixed"
    assert skel.joint_types[skel.index("ball_arm")] == "ball"
    np.testing.assert_allclose(np.rad2deg(skel.angle_hi[skel.index("ball_arm")]), np.rad2deg(1.2), atol=1e-4)
    twist = skel.index("empty")  # hinge with ref=0.3: limits measured from ref
    np.testing.assert_allclose([skel.angle_lo[twist, 0], skel.angle_hi[twist, 0]], [-1.3, 0.7], atol=1e-6)
    assert float(skel.length[twist]) == 0 and float(skel.radius[twist]) == 0  # no geometry
    assert skel.joint_types[skel.index("ellip/e1")] == "hinge" and skel.joint_types[skel.index("ellip")] == "ball"
    spin = skel.index("meshy")  # unlimited hinge
    np.testing.assert_allclose([skel.angle_lo[spin, 0], skel.angle_hi[spin, 0]], [-np.pi, np.pi], atol=1e-6)
    pose = pose_from_qpos(skel, m, m.qpos0)  # qpos0 is the rest pose
    np.testing.assert_allclose(pose.angles, 0, atol=1e-7)


def test_planar_root_joints_are_the_root_pose_and_slides_are_searched():
    m, skel = model_and_skeleton("planar")
    torso = skel.index("torso")  # rootx, rootz, rooty: the root pose's own degrees of freedom
    assert skel.parents[torso] == -1 and skel.joint_types[torso] == "fixed"
    np.testing.assert_allclose(skel.offset[torso], 0, atol=0)
    np.testing.assert_allclose(skel.rest_rotation[torso], np.eye(3), atol=0)
    assert not any(n.startswith("torso/") for n in skel.link_names)
    tele = skel.index("shin")  # a slide's pos does not matter (it moves the whole frame): no extra chain link
    assert skel.joint_types[tele] == "slide" and not any(n.startswith("shin/") for n in skel.link_names)
    np.testing.assert_allclose([skel.angle_lo[tele, 0], skel.angle_hi[tele, 0]], [-0.07, 0.13], atol=1e-6)
    assert skel.joint_types[skel.index("foot/ankle_slide")] == "slide"
    assert skel.joint_types[skel.index("foot")] == "hinge"
    rail = skel.index("tail")  # unlimited: within the model's size (its body geoms; the 5 m floor left out)
    d = mujoco.MjData(m)
    mujoco.mj_kinematics(m, d)
    body = m.geom_bodyid > 0
    c = d.geom_xpos[body].mean(0)
    reach = np.max(np.linalg.norm(d.geom_xpos[body] - c, axis=1) + m.geom_rbound[body])
    assert 0.5 < reach < 1.0  # the walker is about a metre and a half tall
    np.testing.assert_allclose([skel.angle_lo[rail, 0], skel.angle_hi[rail, 0]], [-reach, reach], rtol=1e-6)
    # searched: the root (7), hip, telescope, ankle slide and hinge, rail
    assert skel.num_dof == 7 + 5
    pose = pose_from_qpos(skel, m, m.qpos0)  # qpos0: the rest pose, the torso where the file puts it
    np.testing.assert_allclose(pose.angles, 0, atol=1e-7)
    np.testing.assert_allclose(pose.root_t, m.body_pos[1], atol=1e-6)


def test_two_top_level_bodies_keep_their_joints():
    m, skel = model_and_skeleton("reacher_like")
    assert skel.joint_types[skel.index("arm")] == "hinge"
    tx = skel.index("target/target_x")
    assert skel.joint_types[tx] == "slide" and skel.joint_types[skel.index("target")] == "slide"
    np.testing.assert_allclose([skel.angle_lo[tx, 0], skel.angle_hi[tx, 0]], [-0.37, 0.17], atol=1e-6)


def test_search_lengths_option():
    m, _ = model_and_skeleton("ant")
    skel = skeleton_from_model(m, search_lengths=True)
    i = skel.index("aux_1")
    L = float(skel.length[i])
    np.testing.assert_allclose([skel.length_lo[i], skel.length_hi[i]], [0.7 * L, 1.3 * L], rtol=1e-6)
    t = skel.index("torso")  # a sphere: zero length stays fixed
    assert float(skel.length_lo[t]) == float(skel.length_hi[t]) == 0
    assert sum(n.endswith(".length") for n in genome_layout(skel).names) == 12


def test_scale_held_at_one_unless_searched():
    """An MJCF model has its robot's size: the scale range is exactly 1 unless searched."""
    from jaxpose.io.capsules import SEARCHED_SCALE_RANGE
    from jaxpose.io.skeleton_file import load_skeleton

    _, skel = model_and_skeleton("ant")
    assert (float(skel.scale_lo), float(skel.scale_hi)) == (1.0, 1.0)
    searched = load_skeleton(fixture("ant"), search_scale=True)
    assert (float(searched.scale_lo), float(searched.scale_hi)) == SEARCHED_SCALE_RANGE


# --------------------------------------------------------------------------- kinematics against MuJoCo


@pytest.mark.parametrize("name", MODELS)
def test_forward_kinematics_matches_mujoco(name):
    m, skel = model_and_skeleton(name)
    d = mujoco.MjData(m)
    rng = np.random.default_rng(7)
    qs = [random_qpos(m, rng) for _ in range(8)]
    links = batched_fk(skel, [pose_from_qpos(skel, m, q) for q in qs])
    for k, q in enumerate(qs):
        d.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        for b in range(1, m.nbody):
            i = skel.index(body_name(m, b))
            np.testing.assert_allclose(links.origin[k, i], d.xpos[b], atol=FK_TOL, err_msg=body_name(m, b))
            np.testing.assert_allclose(links.R_world_link[k, i], d.xmat[b].reshape(3, 3), atol=FK_TOL)


def test_ant_capsules_match_mujoco_capsules():
    m, skel = model_and_skeleton("ant")
    d, links = posed_at_random(m, skel, np.random.default_rng(3))
    for g in range(m.ngeom):
        if m.geom_type[g] != mujoco.mjtGeom.mjGEOM_CAPSULE:
            continue
        i = skel.index(body_name(m, m.geom_bodyid[g]))
        r, h = m.geom_size[g][:2]
        z = d.geom_xmat[g].reshape(3, 3)[:, 2]
        ends = {tuple(np.round(d.geom_xpos[g] + s * h * z, 5)) for s in (-1, 1)}
        got = {tuple(np.round(np.asarray(p[0, i], float), 5)) for p in (links.start, links.end)}
        assert max(min(np.abs(np.subtract(a, b)).max() for b in got) for a in ends) < FK_TOL
        assert float(links.radius[0, i]) == pytest.approx(r, abs=1e-6)


def _surface_points(m, d, g, rng):
    """Points on (or the extreme points of) geom g, world frame."""
    t, size = m.geom_type[g], m.geom_size[g]
    R, p = d.geom_xmat[g].reshape(3, 3), d.geom_xpos[g]
    u = rng.normal(size=(200, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    G = mujoco.mjtGeom
    if t == G.mjGEOM_SPHERE:
        local = size[0] * u
    elif t == G.mjGEOM_CAPSULE:
        local = size[0] * u + np.where(u[:, 2:] > 0, 1, -1) * [0, 0, size[1]]
    elif t == G.mjGEOM_CYLINDER:
        ang = rng.uniform(0, 2 * np.pi, 200)
        local = np.stack([size[0] * np.cos(ang), size[0] * np.sin(ang), rng.choice([-1, 1], 200) * size[1]], 1)
    elif t == G.mjGEOM_ELLIPSOID:
        local = size * u
    elif t == G.mjGEOM_BOX:
        local = size * np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)])
    elif t == G.mjGEOM_MESH:
        mid = m.geom_dataid[g]
        local = m.mesh_vert[m.mesh_vertadr[mid] : m.mesh_vertadr[mid] + m.mesh_vertnum[mid]]
    else:
        return np.zeros((0, 3))
    return p + local @ R.T


@pytest.mark.parametrize("name", MODELS)
def test_capsules_enclose_every_geom(name):
    m, skel = model_and_skeleton(name)
    rng = np.random.default_rng(1)
    d, links = posed_at_random(m, skel, rng)
    for g in range(m.ngeom):
        if m.geom_bodyid[g] == 0:
            continue
        i = skel.index(body_name(m, m.geom_bodyid[g]))
        a, b, r = (np.asarray(x[0, i], float) for x in (links.start, links.end, links.radius))
        pts = _surface_points(m, d, g, rng)
        ab = b - a
        s = np.clip((pts - a) @ ab / max(ab @ ab, 1e-300), 0, 1) if ab @ ab > 0 else np.zeros(len(pts))
        dist = np.linalg.norm(pts - (a + s[:, None] * ab), axis=1)
        assert np.all(dist <= r + 1e-5), (name, body_name(m, m.geom_bodyid[g]), dist.max(), r)


def test_box_becomes_capsule_along_longest_side():
    _, skel = model_and_skeleton("gadget")
    i = skel.index("base")  # box half sizes 0.1, 0.05, 0.02
    assert float(skel.length[i]) == pytest.approx(0.2, abs=1e-6)
    assert float(skel.radius[i]) == pytest.approx(np.hypot(0.05, 0.02), abs=1e-6)
    np.testing.assert_allclose(np.abs(skel.seg_dir[i]), [1, 0, 0], atol=1e-6)


def test_quat_to_matrix_matches_mujoco():
    q = np.array([0.3, -0.5, 0.7, 0.2])
    q /= np.linalg.norm(q)
    out = np.zeros(9)
    mujoco.mju_quat2Mat(out, q)
    np.testing.assert_allclose(quat_to_matrix(q), out.reshape(3, 3), atol=1e-12)


# --------------------------------------------------------------------------- bad files


def write(tmp_path, text, name="model.xml"):
    p = tmp_path / name
    p.write_text(text)
    return str(p)


BODY = '<body name="{n}"{extra}><geom size=".1"/>{inner}</body>'


@pytest.mark.parametrize(
    "text, words",
    [
        ("<mujoco><worldbody><body></mujoco>", ["MuJoCo cannot compile", "XML"]),
        ('<mujoco><worldbody><body name="a"><joint type="bogus"/><geom size=".1"/></body></worldbody></mujoco>',
         ["MuJoCo cannot compile", "bogus"]),
        ('<mujoco><worldbody><geom type="plane" size="1 1 1"/></worldbody></mujoco>', ["no bodies"]),
        ('<mujoco><worldbody><body name="a"><freejoint/><geom size=".1"/></body>'
         '<body name="b"><freejoint/><geom size=".1"/></body></worldbody></mujoco>', ["free joints", "'a'", "'b'"]),
        ('<mujoco><worldbody><body name="a"><freejoint/><geom size=".1"/></body>'
         '<body name="b"><geom size=".1"/></body></worldbody></mujoco>', ["floats freely", "'b'"]),
    ],
)
def test_bad_files_raise_one_clear_error(tmp_path, text, words):
    path = write(tmp_path, text)
    with pytest.raises(SkeletonError) as e:
        load_skeleton(path)
    msg = str(e.value)
    assert msg.startswith(path) and "\n" not in msg
    for w in words:
        assert w in msg, msg


def test_missing_file():
    with pytest.raises(SkeletonError, match="not found"):
        load_mjcf(os.path.join(FIXTURES, "no_such_model.xml"))


def test_missing_mujoco_extra(monkeypatch):
    monkeypatch.setitem(sys.modules, "mujoco", None)  # makes `import mujoco` fail
    with pytest.raises(SkeletonError, match=r"pip install 'jaxpose\[mujoco\]'"):
        load_mjcf(fixture("ant"))
