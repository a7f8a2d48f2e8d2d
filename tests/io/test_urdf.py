"""URDF importer: mapping, geometry, forward kinematics against a NumPy oracle and MuJoCo, bad files."""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET

import jax
import numpy as np
import pytest

from jaxpose.errors import SkeletonError
from jaxpose.io.skeleton_file import load_skeleton
from jaxpose.io import capsules as C
from jaxpose.io.urdf import DEFAULT_MESH_RADIUS, load_urdf
from jaxpose.kinematics import forward_kinematics
from jaxpose.genome import genome_layout
from jaxpose.skeleton import Pose

FIXTURES = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "fixtures")
FK_TOL = 1e-5  # metres and matrix entries; jaxpose runs in float32


def fixture(name):
    return os.path.join(FIXTURES, f"{name}.urdf")


# --------------------------------------------------------------------------- an independent oracle


def _rot(axis, angle):
    """Rotation about a unit axis via the matrix exponential of its cross-product matrix."""
    x, y, z = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -z, y], [z, 0, -x], [-y, x, 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def _origin_T(el):
    T = np.eye(4)
    o = el.find("origin")
    if o is not None:
        r, p, y = map(float, (o.get("rpy") or "0 0 0").split())
        T[:3, :3] = _rot([0, 0, 1], y) @ _rot([0, 1, 0], p) @ _rot([1, 0, 0], r)
        T[:3, 3] = list(map(float, (o.get("xyz") or "0 0 0").split()))
    return T


def oracle_fk(path, q):
    """World 4x4 transform of every link for joint values ``q`` (dict joint name -> angle or, for a
    prismatic joint, displacement); root at identity."""
    root = ET.parse(path).getroot()
    joints = {j.find("child").get("link"): j for j in root.findall("joint")}
    out = {}

    def T(link):
        if link not in out:
            j = joints.get(link)
            if j is None:
                out[link] = np.eye(4)
            else:
                M = T(j.find("parent").get("link")) @ _origin_T(j)
                if j.get("type") != "fixed":
                    a = j.find("axis")
                    axis = list(map(float, a.get("xyz").split())) if a is not None else [1, 0, 0]
                    J = np.eye(4)
                    if j.get("type") == "prismatic":  # a translation along the axis, metres
                        J[:3, 3] = q[j.get("name")] * np.asarray(axis) / np.linalg.norm(axis)
                    else:
                        J[:3, :3] = _rot(axis, q[j.get("name")])
                    M = M @ J
                out[link] = M
        return out[link]

    for link in root.findall("link"):
        T(link.get("name"))
    return out


def hinge_joint_names(path):
    """Joint name of every moving (hinge or slide) link, by link name."""
    root = ET.parse(path).getroot()
    return {j.find("child").get("link"): j.get("name") for j in root.findall("joint") if j.get("type") != "fixed"}


def random_pose(skel, rng):
    lo, hi = np.asarray(skel.angle_lo), np.asarray(skel.angle_hi)
    angles = rng.uniform(lo, hi)
    return Pose(np.zeros(3, np.float32), np.zeros(3, np.float32), np.float32(1.0),
                angles.astype(np.float32), np.asarray(skel.length))


def batched_fk(skel, poses):
    stacked = jax.tree.map(lambda *a: np.stack(a), *poses)
    return jax.jit(jax.vmap(forward_kinematics, in_axes=(None, 0)))(skel, stacked)


# --------------------------------------------------------------------------- mapping


def test_chain_mapping():
    skel = load_skeleton(fixture("chain"), max_capsules=1)  # through the dispatcher; one capsule per link
    assert skel.name == "chain"
    assert skel.link_names == ("base", "mount", "link1", "sensor", "link2", "tip")
    assert skel.joint_types == ("fixed", "fixed", "hinge", "fixed", "hinge", "fixed")
    assert skel.parents == (-1, 0, 1, 2, 3, 4)
    assert skel.num_dof == 7 + 2
    i = skel.index("link1")
    np.testing.assert_allclose([skel.angle_lo[i, 0], skel.angle_hi[i, 0]], [-1.0, 1.5], atol=1e-6)
    j = skel.index("link2")  # continuous: unlimited
    np.testing.assert_allclose([skel.angle_lo[j, 0], skel.angle_hi[j, 0]], [-np.pi, np.pi], atol=1e-6)
    np.testing.assert_allclose(skel.offset[skel.index("mount")], [0.1, 0.05, 0.04], atol=1e-7)
    assert np.all(np.asarray(skel.attach) == 0)


def test_chain_geometry():
    skel = load_urdf(fixture("chain"), max_capsules=1)  # one capsule per link (tests/io/test_capsules.py: several)
    b = skel.index("base")  # collision box 0.3 x 0.2 x 0.04 (the visual sphere of radius 1 is ignored)
    assert float(skel.length[b]) == pytest.approx(0.3, abs=1e-6)
    assert float(skel.radius[b]) == pytest.approx(np.hypot(0.1, 0.02), abs=1e-6)
    np.testing.assert_allclose(np.abs(skel.seg_dir[b]), [1, 0, 0], atol=1e-6)
    i = skel.index("link1")  # cylinder z in [0, 0.2], r 0.03, and a ball r 0.04 at z 0.22: one capsule
    assert float(skel.radius[i]) == pytest.approx(0.04, abs=1e-6)
    start, end = np.asarray(skel.seg_start[i]), np.asarray(skel.seg_start[i] + skel.length[i] * skel.seg_dir[i])
    zs = sorted([start[2], end[2]])
    # the cylinder's end balls (r 0.03) fit 0.01 inside the ends of a capsule of radius 0.04
    np.testing.assert_allclose(zs, [0.01, 0.22], atol=1e-6)
    j = skel.index("link2")  # visual-only capsule along x from 0 to 0.15
    assert float(skel.length[j]) == pytest.approx(0.15, abs=1e-6) and float(skel.radius[j]) == pytest.approx(0.025)
    for name in ("mount", "sensor"):  # no geometry: kinematics only
        k = skel.index(name)
        assert float(skel.length[k]) == 0 and float(skel.radius[k]) == 0


def test_mesh_only_link():
    skel = load_urdf(fixture("mesh_link"))
    g = skel.index("gripper")
    assert float(skel.length[g]) == 0
    assert float(skel.radius[g]) == pytest.approx(0.5 * DEFAULT_MESH_RADIUS)
    np.testing.assert_allclose(skel.seg_start[g], [0.03, 0, 0.01], atol=1e-7)


def test_search_lengths_option():
    skel = load_urdf(fixture("arm7"), search_lengths=True, max_capsules=1)
    i = skel.index("upper_arm_link")
    np.testing.assert_allclose([skel.length_lo[i], skel.length_hi[i]], [0.21, 0.39], rtol=1e-5)
    w = skel.index("wrist1_link")  # a ball: zero length stays fixed
    assert float(skel.length_lo[w]) == float(skel.length_hi[w]) == 0
    names = genome_layout(skel).names
    assert sum(n.endswith(".length") for n in names) == 7
    fixed = load_urdf(fixture("arm7"))
    assert not any(n.endswith(".length") for n in genome_layout(fixed).names)
    # several capsules per link (the default): only the links' own capsules are searched
    several = load_urdf(fixture("arm7"), search_lengths=True)
    assert several.num_links > skel.num_links
    assert sum(n.endswith(".length") for n in genome_layout(several).names) == 7


# --------------------------------------------------------------------------- kinematics


@pytest.mark.parametrize("name", ["chain", "arm7", "mesh_link", "gripper"])
def test_forward_kinematics_matches_numpy_oracle(name):
    path = fixture(name)
    skel = load_urdf(path)
    joint_of = hinge_joint_names(path)
    rng = np.random.default_rng(0)
    poses = [random_pose(skel, rng) for _ in range(8)]
    links = batched_fk(skel, poses)
    for k, pose in enumerate(poses):
        q = {joint_of[n]: float(pose.angles[i, 0]) for i, n in enumerate(skel.link_names) if n in joint_of}
        T = oracle_fk(path, q)
        for i, n in enumerate(skel.link_names):
            link = n.split(C.EXTRA_CAPSULE)[0]  # an extra capsule of a link is in the link's frame
            np.testing.assert_allclose(links.origin[k, i], T[link][:3, 3], atol=FK_TOL, err_msg=n)
            np.testing.assert_allclose(links.R_world_link[k, i], T[link][:3, :3], atol=FK_TOL, err_msg=n)


@pytest.mark.parametrize("name", ["arm7", "gripper"])
def test_forward_kinematics_matches_mujoco(name):
    mujoco = pytest.importorskip("mujoco")
    path = fixture(name)
    m = mujoco.MjModel.from_xml_path(path)  # MuJoCo's own URDF compiler (the file keeps every link)
    d = mujoco.MjData(m)
    skel = load_urdf(path)
    rng = np.random.default_rng(5)
    poses = [random_pose(skel, rng) for _ in range(8)]
    links = batched_fk(skel, poses)
    for k, pose in enumerate(poses):
        for j in range(m.njnt):
            d.qpos[m.jnt_qposadr[j]] = pose.angles[skel.index(m.body(m.jnt_bodyid[j]).name), 0]
        mujoco.mj_kinematics(m, d)
        for b in range(1, m.nbody):
            i = skel.index(m.body(b).name)
            np.testing.assert_allclose(links.origin[k, i], d.xpos[b], atol=FK_TOL)
            np.testing.assert_allclose(links.R_world_link[k, i], d.xmat[b].reshape(3, 3), atol=FK_TOL)


# --------------------------------------------------------------------------- bad files


def robot(body):
    return f'<?xml version="1.0"?>\n<robot name="r">\n{body}\n</robot>\n'


LINKS = '<link name="a"/><link name="b"/><link name="c"/>'


def joint(name, jtype, parent, child, extra=""):
    return f'<joint name="{name}" type="{jtype}"><parent link="{parent}"/><child link="{child}"/>{extra}</joint>'


LIMIT = '<limit lower="-1" upper="1"/>'

BAD = [
    ("<robot><link name='a'></robot>", ["malformed XML", "line"]),
    ('<?xml version="1.0"?><sdf version="1.6"/>', ["not a URDF", "<sdf>"]),
    (robot(""), ["no links"]),
    (robot('<link name="a"/><link name="a"/>'), ["duplicate link", "'a'"]),
    (robot(LINKS + joint("j1", "revolute", "a", "b", LIMIT) + joint("j2", "slider", "b", "c")),
     ["joint 'j2'", "unknown joint type 'slider'"]),
    (robot(LINKS + joint("j1", "prismatic", "a", "b") + joint("j2", "fixed", "b", "c")),
     ["joint 'j1'", "a prismatic joint needs a <limit"]),
    (robot(LINKS + joint("j1", "floating", "a", "b") + joint("j2", "fixed", "b", "c")), ["joint 'j1'", "floating"]),
    (robot(LINKS + joint("j1", "fixed", "a", "b") + joint("j2", "fixed", "b", "ghost")),
     ["joint 'j2'", "missing child link 'ghost'"]),
    (robot(LINKS + joint("j1", "fixed", "a", "c") + joint("j2", "fixed", "b", "c")),
     ["closed loop", "'c'", "'j1'", "'j2'"]),
    (robot(LINKS + joint("j1", "fixed", "a", "b") + joint("j2", "fixed", "b", "c") + joint("j3", "fixed", "c", "a")),
     ["closed loop"]),
    (robot(LINKS + '<link name="d"/>' + joint("j1", "fixed", "a", "b") + joint("j2", "fixed", "c", "d")
           + joint("j3", "fixed", "d", "c")), ["closed loop", "cycle"]),
    (robot(LINKS + joint("j1", "fixed", "a", "b")), ["2 root links", "'a'", "'c'"]),
    (robot(LINKS + joint("j1", "revolute", "a", "b") + joint("j2", "fixed", "b", "c")), ["joint 'j1'", "<limit"]),
    (robot(LINKS + joint("j1", "revolute", "a", "b", '<axis xyz="0 0 0"/>' + LIMIT) + joint("j2", "fixed", "b", "c")),
     ["joint 'j1'", "non-zero"]),
    (robot(LINKS + joint("j1", "fixed", "a", "b", '<origin xyz="1 2"/>') + joint("j2", "fixed", "b", "c")),
     ["joint 'j1'", "xyz", "3 numbers"]),
    (robot('<link name="a"><collision><geometry><cone radius="1"/></geometry></collision></link>'),
     ["link 'a'", "unsupported geometry <cone>"]),
    (robot('<link name="a"><visual><geometry><box/></geometry></visual></link>'), ["link 'a'", "'size'"]),
]


@pytest.mark.parametrize("text, words", BAD)
def test_bad_files_raise_one_clear_error(tmp_path, text, words):
    path = tmp_path / "robot.urdf"
    path.write_text(text)
    with pytest.raises(SkeletonError) as e:
        load_skeleton(str(path))
    msg = str(e.value)
    assert msg.startswith(str(path)) and "\n" not in msg
    for w in words:
        assert w in msg, msg
        if w.startswith("joint '"):
            assert msg.count(w) == 1, msg  # the joint is named once, not again by a nested message


def test_missing_file():
    with pytest.raises(SkeletonError, match="not found"):
        load_urdf(os.path.join(FIXTURES, "no_such_robot.urdf"))


# --------------------------------------------------------------------------- mesh files


def _mesh_urdf(tmp_path, filename, origin='xyz="0.02 0 0.01" rpy="0 0.3 0.5"', scale="0.5 2 1"):
    p = tmp_path / "robot.urdf"
    p.write_text(
        f'<robot name="m"><link name="base"/><link name="tool"><visual><origin {origin}/>'
        f'<geometry><mesh filename="{filename}" scale="{scale}"/></geometry></visual></link>'
        '<joint name="j" type="revolute"><parent link="base"/><child link="tool"/><axis xyz="0 0 1"/>'
        '<limit lower="-1" upper="1"/></joint></robot>'
    )
    return str(p)


def _box_vertices(size):
    return np.array([[x, y, z] for x in (0, size[0]) for y in (0, size[1]) for z in (0, size[2])], float)


def _write_binary_stl(path, vertices):
    import struct

    tris = vertices[np.array([[0, 1, 3], [4, 5, 7], [0, 2, 6], [1, 3, 7]])]
    with open(path, "wb") as f:
        f.write(b"\0" * 80 + struct.pack("<I", len(tris)))
        for t in tris:
            f.write(struct.pack("<3f", 0, 0, 1) + t.astype("<f4").tobytes() + b"\0\0")


def _assert_encloses(skel, link, points):
    """Every point lies in the link's capsule (the independent point-to-segment formula)."""
    i = skel.index(link)
    a = np.asarray(skel.seg_start[i], float)
    d = np.asarray(skel.seg_dir[i], float)
    L, r = float(skel.length[i]), float(skel.radius[i])
    t = np.clip((points - a) @ d, 0.0, L)
    dist = np.linalg.norm(points - (a + t[:, None] * d), axis=1)
    assert np.all(dist <= r + 1e-5), (dist.max(), r)
    return L, r


@pytest.mark.parametrize("kind", ["obj", "stl-binary", "stl-ascii"])
def test_mesh_files_are_read_and_enclosed(tmp_path, kind):
    v = _box_vertices([0.3, 0.05, 0.04])
    if kind == "obj":
        (tmp_path / "part.obj").write_text("# part\n" + "".join(f"v {x} {y} {z}\n" for x, y, z in v) + "f 1 2 3\n")
        name = "part.obj"
    elif kind == "stl-binary":
        _write_binary_stl(tmp_path / "part.stl", v)
        name = "part.stl"
    else:
        facets = "".join(f"facet normal 0 0 1\nouter loop\nvertex {a[0]} {a[1]} {a[2]}\nvertex {b[0]} {b[1]} {b[2]}\n"
                         f"vertex {c[0]} {c[1]} {c[2]}\nendloop\nendfacet\n" for a, b, c in (v[:3], v[3:6], v[5:8]))
        (tmp_path / "part.stl").write_text(f"solid part\n{facets}endsolid part\n")
        name = "part.stl"
    skel = load_urdf(_mesh_urdf(tmp_path, name))
    # the vertices in the link frame: scale, then the visual origin (URDF rpy = Rz Ry Rx)
    pitch, yaw = 0.3, 0.5  # roll 0
    cz, sz, cy, sy = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch)
    R = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]]) @ np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    pts = np.array([0.02, 0, 0.01]) + (v * [0.5, 2.0, 1.0]) @ R.T
    L, r = _assert_encloses(skel, "tool", pts)
    # tight: the long side (0.15 m after scaling) is the axis, not a stand-in ball
    assert 0.05 < L <= 0.15 + 1e-6 and r < 0.1


def test_mesh_behind_a_package_url_is_found_beside_the_urdf(tmp_path):
    (tmp_path / "meshes").mkdir()
    (tmp_path / "meshes" / "part.obj").write_text("v 0 0 0\nv 0.4 0 0\nv 0 0.02 0\n")
    skel = load_urdf(_mesh_urdf(tmp_path, "package://my_robot/meshes/part.obj", origin='xyz="0 0 0"', scale="1 1 1"))
    L, _ = _assert_encloses(skel, "tool", np.array([[0, 0, 0], [0.4, 0, 0], [0, 0.02, 0]], float))
    assert L > 0.3


def test_unreadable_mesh_is_one_clear_error(tmp_path):
    (tmp_path / "bad.obj").write_text("v 0 zero 0\n")
    with pytest.raises(SkeletonError) as e:
        load_urdf(_mesh_urdf(tmp_path, "bad.obj"))
    msg = str(e.value)
    assert "robot.urdf" in msg and "bad.obj" in msg and "malformed vertex line" in msg and "\n" not in msg
    (tmp_path / "empty.stl").write_bytes(b"\0" * 84)
    with pytest.raises(SkeletonError, match="the mesh holds no vertex"):
        load_urdf(_mesh_urdf(tmp_path, "empty.stl"))


def test_unresolvable_or_other_format_mesh_stands_in_as_a_ball(tmp_path):
    for name in ("package://nowhere/m.stl", "part.dae"):
        skel = load_urdf(_mesh_urdf(tmp_path, name, origin='xyz="0.02 0 0.01"', scale="0.5 0.5 0.5"))
        i = skel.index("tool")
        assert float(skel.length[i]) == 0 and float(skel.radius[i]) == pytest.approx(0.5 * DEFAULT_MESH_RADIUS)


def test_load_skeleton_search_lengths_for_robot_files_only(tmp_path):
    from jaxpose.io.skeleton_file import load_skeleton

    searched = load_skeleton(fixture("arm7"), search_lengths=True)
    assert sum(n.endswith(".length") for n in genome_layout(searched).names) == 7
    assert not any(n.endswith(".length") for n in genome_layout(load_skeleton(fixture("arm7"))).names)
    with pytest.raises(SkeletonError, match="searching lengths is an option for robot files"):
        load_skeleton("spider", search_lengths=True)


def test_robot_scale_held_at_one_unless_searched():
    """A robot file has its robot's size: the scale range is exactly 1 unless ``search_scale``
    (the search range then), which a native file refuses (it sets scale_range)."""
    from jaxpose.io.capsules import SEARCHED_SCALE_RANGE
    from jaxpose.io.skeleton_file import load_skeleton

    held = load_skeleton(fixture("arm7"))
    assert (float(held.scale_lo), float(held.scale_hi)) == (1.0, 1.0)
    searched = load_skeleton(fixture("arm7"), search_scale=True)
    assert (float(searched.scale_lo), float(searched.scale_hi)) == SEARCHED_SCALE_RANGE
    assert load_urdf(fixture("arm7"), scale_range=(0.7, 1.4)).scale_hi == pytest.approx(1.4)
    with pytest.raises(SkeletonError, match="searching the scale is an option for robot files"):
        load_skeleton("spider", search_scale=True)


def test_prismatic_and_spherical_joints(tmp_path):
    skel = load_urdf(fixture("gripper"), max_capsules=1)
    assert skel.joint_types == ("fixed", "hinge", "slide", "hinge", "slide", "slide")
    i = skel.index("column")
    np.testing.assert_allclose([skel.angle_lo[i, 0], skel.angle_hi[i, 0]], [-0.05, 0.3], atol=1e-7)  # metres
    np.testing.assert_allclose(skel.axis[skel.index("finger_right")], [0, -1, 0], atol=1e-7)
    # the fingers slide in opposite directions over the same range: interchangeable for the metrics
    assert skel.orbit[skel.index("finger_left")] == skel.orbit[skel.index("finger_right")]
    path = tmp_path / "ball.urdf"
    path.write_text(robot(LINKS + joint("j1", "spherical", "a", "b") + joint("j2", "fixed", "b", "c")))
    ball = load_urdf(str(path))
    assert ball.joint_types[ball.index("b")] == "ball"
    np.testing.assert_allclose(ball.angle_hi[ball.index("b")], [np.pi] * 3, atol=1e-6)


def test_a_mesh_link_gets_the_capsule_fitted_to_its_surface(tmp_path):
    """Vertices sampled (unevenly, as CAD meshes are) on a known capsule's surface, plus a small
    knob sticking out 3 cm: the link's capsule is that capsule within a millimetre, not the one
    enclosing the knob too."""
    rng = np.random.default_rng(4)
    a, b, r = np.array([0.01, -0.02, 0.03]), np.array([0.05, 0.21, 0.09]), 0.04
    axis = (b - a) / np.linalg.norm(b - a)
    e1 = np.cross(axis, [1.0, 0, 0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(axis, e1)
    t = np.concatenate([rng.uniform(0, 1, 300), rng.uniform(0.8, 1, 500)])  # denser at one end
    phi = rng.uniform(0, 2 * np.pi, len(t))
    side = a + np.outer(t * np.linalg.norm(b - a), axis) + r * (np.outer(np.cos(phi), e1) + np.outer(np.sin(phi), e2))
    caps = rng.normal(size=(200, 3))
    caps = r * caps / np.linalg.norm(caps, axis=1, keepdims=True)
    caps += np.where((caps @ axis)[:, None] > 0, b, a)  # the hemispheres' outer halves
    caps = caps[((caps - a) @ axis < 0) | ((caps - b) @ axis > 0)]
    knob = a + 0.5 * (b - a) + (r + 0.03) * e1 + rng.normal(0, 0.003, (12, 3))
    v = np.concatenate([side, caps, knob])
    (tmp_path / "part.obj").write_text("".join(f"v {x} {y} {z}\n" for x, y, z in v))
    skel = load_urdf(_mesh_urdf(tmp_path, "part.obj", origin='xyz="0 0 0" rpy="0 0 0"', scale="1 1 1"))
    i = skel.index("tool")
    s, d, L = np.asarray(skel.seg_start[i]), np.asarray(skel.seg_dir[i]), float(skel.length[i])
    ends = sorted([s, s + L * d], key=lambda p: float(p @ axis))
    np.testing.assert_allclose(ends, [a, b], atol=1e-3)
    assert float(skel.radius[i]) == pytest.approx(r, abs=1e-3)
    assert C.enclosing_capsule([C.points_shape(v)])[3] > r + 0.01  # what enclosing would have given
    # a mesh of fewer than 16 vertices keeps the enclosing capsule (test_mesh_files_are_read_and_enclosed)
