"""Several capsules per link (``max_capsules``): slabs of flat shapes, the capsules' choice, and the
extra capsules as fixed child links of robot files."""

from __future__ import annotations

import os

import numpy as np
import pytest

from jaxpose.errors import SkeletonError
from jaxpose.geometry import rpy_matrix
from jaxpose.io import capsules as C
from jaxpose.io.urdf import load_urdf
from jaxpose.io.skeleton_file import load_skeleton
from jaxpose.kinematics import forward_kinematics
from jaxpose.genome import genome_layout
from jaxpose.skeleton import rest_pose

FIXTURES = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "fixtures")
RNG = np.random.default_rng(3)


def _rotation(seed):
    q, _ = np.linalg.qr(np.random.default_rng(seed).normal(size=(3, 3)))
    return q * np.sign(np.linalg.det(q))


def _in_box(p, pos, R, half):
    return np.all(np.abs((p - pos) @ R) <= np.asarray(half) + 1e-9, axis=-1)


def _box_points(pos, R, half, n=4000):
    return pos + (RNG.uniform(-1, 1, (n, 3)) * half) @ R.T


def _box_surface(pos, R, half, n=6000):
    """Points spread uniformly over a box's six faces (by area)."""
    half = np.asarray(half, float)
    areas = np.array([half[1] * half[2], half[0] * half[2], half[0] * half[1]] * 2)
    face = RNG.choice(6, n, p=areas / areas.sum())
    u = RNG.uniform(-1, 1, (n, 3))
    u[np.arange(n), face % 3] = np.where(face < 3, 1.0, -1.0)
    return pos + (u * half) @ R.T


def _capsule_distances(p, caps):
    """``(n, k)`` distances of points to the surfaces of capsules ``(start, dir, length, radius)``."""
    out = []
    for a, d, length, r in caps:
        a, d = np.asarray(a, float), np.asarray(d, float)
        t = np.clip((p - a) @ d, 0.0, length)
        out.append(np.linalg.norm(p - (a + t[:, None] * d), axis=1) - r)
    return np.stack(out, 1)


def _disk_points(pos, R, radius, half_height, n=4000):
    rho, phi = radius * np.sqrt(RNG.uniform(0, 1, n)), RNG.uniform(0, 2 * np.pi, n)
    return pos + np.stack([rho * np.cos(phi), rho * np.sin(phi), RNG.uniform(-half_height, half_height, n)], 1) @ R.T


def _ends(caps):
    return np.array([[a, np.asarray(a) + length * np.asarray(d)] for a, d, length, _ in caps])  # (k, 2, 3)


def _slab_capsules(shape, k):
    return [C.link_capsule([p]) for p in shape.split(k)]


@pytest.mark.parametrize("k", [2, 4, 6])
def test_box_slabs_lie_side_by_side_and_end_at_its_end_faces(k):
    pos, R, half = np.array([0.2, 0.0, -0.1]), _rotation(4), np.array([0.15, 0.1, 0.015])
    box = C.box_shape(pos, R, half)
    caps = _slab_capsules(box, k)
    assert len(caps) == k
    # the segments run along the box's longest side, side by side across its middle one
    local = (_ends(caps) - pos) @ R  # (k, 2, 3) in the box's frame
    np.testing.assert_allclose(local[:, :, 2], 0.0, atol=1e-9)
    np.testing.assert_allclose(np.sort(local[:, 0, 1]), (np.arange(k) + 0.5) * 0.2 / k - 0.1, atol=1e-9)
    # their caps end at the end faces, not past them (an enclosing capsule's stick out by its radius)
    tips = np.abs(local[:, :, 0]) + np.array([c[3] for c in caps])[:, None]
    np.testing.assert_allclose(tips, half[0], atol=1e-9)
    # each slab's radius: the disk as large as its cross-section
    np.testing.assert_allclose([c[3] for c in caps], np.sqrt(4 * (0.1 / k) * 0.015 / np.pi), rtol=1e-9)


@pytest.mark.parametrize("k", [2, 4])
def test_disk_slabs_end_on_its_rim(k):
    pos, R, radius, half_height = np.array([0.0, 0.1, 0.0]), _rotation(2), 0.08, 0.02
    caps = _slab_capsules(C.cylinder_shape(pos, R, radius, half_height), k)
    assert len(caps) == k
    local = (_ends(caps) - pos) @ R
    np.testing.assert_allclose(local[:, :, 2], 0.0, atol=1e-9)  # in the disk's middle plane
    reach = np.hypot(local[:, :, 1], np.abs(local[:, :, 0]) + np.array([c[3] for c in caps])[:, None])
    np.testing.assert_allclose(reach, radius, atol=1e-9)  # each capsule's tip on the rim


@pytest.mark.parametrize("kind", ["box", "disk"])
def test_shape_samples_lie_on_the_surface_and_cover_it(kind):
    """The surface samples that judge the capsules, against the shapes' own definitions."""
    pos, R = np.array([0.1, 0.2, 0.3]), _rotation(5)
    if kind == "box":
        half = np.array([0.15, 0.1, 0.015])
        pts, area = C.box_shape(pos, R, half).sample(2000)
        local = np.abs((pts - pos) @ R) / half
        assert np.allclose(local.max(1), 1.0) and np.all(local <= 1 + 1e-9)
        assert area == pytest.approx(8 * (0.15 * 0.1 + 0.1 * 0.015 + 0.15 * 0.015))
        on_face = np.isclose(local, 1.0)
        expected = np.array([0.1 * 0.015, 0.15 * 0.015, 0.15 * 0.1])  # areas of the faces across x, y, z
        np.testing.assert_allclose(on_face.mean(0), expected / expected.sum(), atol=0.03)
    else:
        radius, hh = 0.08, 0.02
        pts, area = C.cylinder_shape(pos, R, radius, hh).sample(2000)
        local = (pts - pos) @ R
        rho, z = np.hypot(local[:, 0], local[:, 1]), local[:, 2]
        on_side = np.isclose(rho, radius)
        assert np.all(on_side | np.isclose(np.abs(z), hh)) and np.all(rho <= radius + 1e-9)
        assert area == pytest.approx(2 * np.pi * radius**2 + 4 * np.pi * radius * hh)
        assert on_side.mean() == pytest.approx(4 * np.pi * radius * hh / area, abs=0.03)


@pytest.mark.parametrize("half", [(0.15, 0.1, 0.015), (0.1335, 0.097, 0.057), (0.05, 0.05, 0.05), (0.2, 0.03, 0.03)])
@pytest.mark.parametrize("budget", [2, 4])
def test_capsules_of_a_box_follow_its_surface_at_least_as_close_as_one(half, budget):
    pos, R = np.array([0.2, 0.0, -0.1]), _rotation(4)
    box = C.box_shape(pos, R, half)
    caps = C.link_capsules([box], budget)
    assert 1 <= len(caps) <= budget
    surface = _box_surface(pos, R, np.asarray(half))  # an independent sample of the surface
    gap = np.mean(np.abs(_capsule_distances(surface, caps).min(1)))
    assert gap <= np.mean(np.abs(_capsule_distances(surface, C.link_capsules([box], 1)).min(1))) + 1e-9
    volumes = [C.capsule_volume(c[3], c[2]) for c in caps]
    assert volumes == sorted(volumes, reverse=True)  # the largest first: the link's own capsule


def test_a_flat_box_and_a_flat_disk_are_cut_a_rod_is_not():
    plate = C.box_shape(np.zeros(3), np.eye(3), (0.15, 0.1, 0.015))
    disk = C.cylinder_shape(np.zeros(3), np.eye(3), 0.08, 0.02)
    rod = C.cylinder_shape(np.zeros(3), np.eye(3), 0.02, 0.2)
    assert len(C.link_capsules([plate], 4)) > 1 and len(C.link_capsules([disk], 4)) > 1
    [cap] = C.link_capsules([rod], 4)
    for a, b in zip(cap, C.link_capsule([rod])):  # a rod keeps its exact enclosing capsule
        np.testing.assert_allclose(a, b)
    surface = _box_surface(np.zeros(3), np.eye(3), np.array([0.15, 0.1, 0.015]))
    gap = np.mean(np.abs(_capsule_distances(surface, C.link_capsules([plate], 4)).min(1)))
    assert gap < 0.5 * np.mean(np.abs(_capsule_distances(surface, C.link_capsules([plate], 1)).min(1)))


def test_one_capsule_is_the_link_capsule():
    shapes = [C.box_shape(np.zeros(3), np.eye(3), (0.1, 0.3, 0.02)), C.sphere_shape(np.array([0.3, 0, 0]), 0.05)]
    [one] = C.link_capsules(shapes, 1)
    for a, b in zip(one, C.link_capsule(shapes)):
        np.testing.assert_array_equal(a, b)


def test_more_shapes_than_capsules_keeps_the_largest_apart():
    big = C.box_shape(np.zeros(3), np.eye(3), (0.3, 0.05, 0.05))
    small = [C.sphere_shape(np.array([0.0, 0.2 + 0.05 * i, 0.0]), 0.02) for i in range(3)]
    caps = C.link_capsules([small[0], big, small[1], small[2]], 2)
    assert len(caps) == 2
    np.testing.assert_allclose(caps[0][2:], C.enclosing_capsule([big])[2:])  # the box alone
    ends = np.array([s.centres[0] for s in small])
    assert np.all(_capsule_distances(ends, caps[1:]).min(1) <= -0.02 + 1e-9)  # the balls in the other one


def _extras(skel):
    return [i for i, n in enumerate(skel.link_names) if C.EXTRA_CAPSULE in n]


@pytest.mark.parametrize("name", ["gripper.urdf", "gadget.xml"])
def test_extra_capsules_are_fixed_children_in_their_links_frame(name):
    if name.endswith(".xml"):
        pytest.importorskip("mujoco")
    path = os.path.join(FIXTURES, name)
    one, four = load_skeleton(path, max_capsules=1), load_skeleton(path, max_capsules=4)
    extras = _extras(four)
    assert extras and not _extras(one)
    assert four.num_links == one.num_links + len(extras)
    assert genome_layout(four).size == genome_layout(one).size  # no new degrees of freedom
    for i in extras:
        parent = four.link_names[four.parents[i]]
        assert four.link_names[i].startswith(parent + C.EXTRA_CAPSULE) and four.joint_types[i] == "fixed"
    # every link but the extras keeps its frame; an extra capsule moves with its link
    pose = rest_pose(four)
    rng = np.random.default_rng(0)
    angles = np.asarray(pose.angles) + rng.uniform(-0.3, 0.3, np.shape(pose.angles))
    pose = pose._replace(angles=angles.astype(np.float32))
    links = forward_kinematics(four, pose)
    R, origin = np.asarray(links.R_world_link), np.asarray(links.origin)
    for i in extras:
        p = four.parents[i]
        np.testing.assert_allclose(R[i], R[p], atol=1e-6)
        np.testing.assert_allclose(origin[i], origin[p], atol=1e-6)


def test_turntable_slabs_cover_the_disk_the_urdf_poses():
    """The gripper's turntable (a cylinder 0.16 wide, 0.04 long, 0.02 above its frame), posed by an
    independent URDF forward kinematics under a tilted root: the turntable's capsules (its own and
    its extra ones, posed by jaxpose) cover it and their axes lie in its middle plane."""
    from test_urdf import hinge_joint_names, oracle_fk

    path = os.path.join(FIXTURES, "gripper.urdf")
    skel = load_skeleton(path, max_capsules=4)
    t = skel.index("turntable")
    caps = [i for i, b in enumerate(skel.bodies) if b == t]
    assert len(caps) > 1  # cut into slabs
    q = {joint: 0.0 for joint in hinge_joint_names(path).values()}
    q["turn"] = 0.7
    root_rpy, root_t = np.array([0.3, -0.4, 0.2]), np.array([0.1, 0.2, 0.3])
    pose = rest_pose(skel)
    angles = np.asarray(pose.angles).copy()
    angles[t, 0] = 0.7
    pose = pose._replace(angles=angles.astype(np.float32), root_rpy=root_rpy.astype(np.float32),
                         root_t=root_t.astype(np.float32))
    links = forward_kinematics(skel, pose)
    T = oracle_fk(path, q)["turntable"]
    R_root = rpy_matrix(root_rpy)
    R, o = R_root @ T[:3, :3], R_root @ T[:3, 3] + root_t
    centre = o + 0.02 * R[:, 2]
    pts = _disk_points(centre, R, 0.08, 0.02)
    s, e, r = (np.asarray(a, float)[caps] for a in (links.start, links.end, links.radius))
    d = _capsule_distances(pts, [(a, (b - a) / np.linalg.norm(b - a), np.linalg.norm(b - a), rr)
                                 for a, b, rr in zip(s, e, r)])
    assert np.mean(d.min(1) <= 1e-6) > 0.6  # two slabs of the disk's cross-section hold 69% of it
    local = (np.concatenate([s, e]) - centre) @ R  # the disk's frame
    assert np.all(np.abs(local[:, 2]) <= 1e-5) and np.all(np.hypot(local[:, 0], local[:, 1]) <= 0.08 + 1e-5)


def test_collision_pairs_treat_a_links_capsules_as_that_link():
    """No collision pair within one link's capsules, nor between them and the parent's or a
    child's (they meet at the joint): by names and the URDF's tree, against the code's pairs."""
    from jaxpose.kinematics import collision_pairs

    path = os.path.join(FIXTURES, "quadruped.urdf")
    skel = load_skeleton(path)
    assert any(C.EXTRA_CAPSULE in n for n in skel.link_names)
    import xml.etree.ElementTree as ET

    parent = {j.find("child").get("link"): j.find("parent").get("link")
              for j in ET.parse(path).getroot().findall("joint")}
    owner = [n.split(C.EXTRA_CAPSULE)[0] for n in skel.link_names]
    expected = {(i, j) for i in range(skel.num_links) for j in range(i + 1, skel.num_links)
                if owner[i] != owner[j] and parent.get(owner[i]) != owner[j] and parent.get(owner[j]) != owner[i]}
    pairs = collision_pairs(skel, 0.8)
    assert set(zip(np.asarray(pairs.i).tolist(), np.asarray(pairs.j).tolist())) == expected


@pytest.mark.parametrize("size", ["0.2 0 0", "0 0 0", "0.2 0.1 0"])
def test_degenerate_boxes_load(tmp_path, size):
    path = tmp_path / "flat.urdf"
    path.write_text(f"""<robot name="flat">
  <link name="a"><collision><geometry><box size="{size}"/></geometry></collision></link>
  <link name="b"><collision><geometry><cylinder radius="0" length="0.1"/></geometry></collision></link>
  <joint name="j" type="revolute"><parent link="a"/><child link="b"/><axis xyz="0 0 1"/>
    <limit lower="-1" upper="1"/></joint>
</robot>""")
    skel = load_skeleton(str(path))
    assert np.all(np.isfinite(np.asarray(skel.length))) and np.all(np.isfinite(np.asarray(skel.radius)))


@pytest.mark.parametrize("value", [0, -1, 2.5, True, "4"])
def test_max_capsules_must_be_a_whole_number_of_at_least_one(value):
    path = os.path.join(FIXTURES, "gripper.urdf")
    for load in (lambda: load_urdf(path, max_capsules=value), lambda: load_skeleton(path, max_capsules=value)):
        with pytest.raises(SkeletonError, match="max_capsules must be a whole number >= 1"):
            load()


def test_an_extra_capsule_name_taken_by_a_link_is_one_clear_error(tmp_path):
    path = tmp_path / "clash.urdf"
    path.write_text("""<robot name="clash">
  <link name="plate"><collision><geometry><box size="0.4 0.3 0.02"/></geometry></collision></link>
  <link name="plate#capsule2"/>
  <joint name="j" type="fixed"><parent link="plate"/><child link="plate#capsule2"/></joint>
</robot>""")
    load_skeleton(str(path), max_capsules=1)  # one capsule per link: no extra links, no clash
    with pytest.raises(SkeletonError, match=r"plate#capsule2.*taken"):
        load_skeleton(str(path), max_capsules=3)
