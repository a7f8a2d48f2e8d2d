"""Forward kinematics against the recursive NumPy oracle, and its invariants."""

from __future__ import annotations

import os
import tomllib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxpose.errors import SkeletonError
from jaxpose.io.skeleton_file import load_skeleton, shipped_skeletons
from jaxpose.kinematics import forward_kinematics
from jaxpose.geometry import axis_angle_matrix, rpy_matrix
from jaxpose.skeleton import LinkSpec, Pose, build_skeleton, rest_pose

from oracles import fk_oracle, pose_dict, rot_axis, rot_x, rot_y, rot_z, rpy, stack_fk

SKELETON_DIR = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "skeletons")
TOL = 1e-5  # metres / matrix entries; jaxpose computes in float32
fk_jit = jax.jit(forward_kinematics)


def raw_links(name):
    with open(os.path.join(SKELETON_DIR, f"{name}.toml"), "rb") as f:
        return tomllib.load(f)["link"]


def random_pose(skel, rng, *, angle_range=np.pi, scale=None, root=True):
    L = skel.num_links
    return Pose(
        root_t=jnp.asarray(rng.uniform(-1, 1, 3) + [0, 0, 2.0] if root else np.zeros(3), jnp.float32),
        root_rpy=jnp.asarray(rng.uniform(-np.pi, np.pi, 3) if root else np.zeros(3), jnp.float32),
        scale=jnp.asarray(rng.uniform(0.5, 2.0) if scale is None else scale, jnp.float32),
        # every DOF random, unused ones included: hinge/slide/fixed joints must ignore them
        angles=jnp.asarray(rng.uniform(-angle_range, angle_range, (L, 3)), jnp.float32),
        lengths=jnp.asarray(rng.uniform(0.05, 0.5, L), jnp.float32),
    )


def assert_matches_oracle(skel, links_desc, pose, fk=fk_jit, tol=TOL):
    got = fk(skel, pose)
    R, origin, start, end, radius = stack_fk(fk_oracle(links_desc, pose_dict(skel, pose)), skel.link_names)
    np.testing.assert_allclose(np.asarray(got.R_world_link), R, atol=tol, rtol=0)
    np.testing.assert_allclose(np.asarray(got.origin), origin, atol=tol, rtol=0)
    np.testing.assert_allclose(np.asarray(got.start), start, atol=tol, rtol=0)
    np.testing.assert_allclose(np.asarray(got.end), end, atol=tol, rtol=0)
    np.testing.assert_allclose(np.asarray(got.radius), radius, atol=tol, rtol=1e-6)


# --------------------------------------------------------------------------- rotation conventions


def test_rotation_helpers_match_elementary_rotations():
    rng = np.random.default_rng(0)
    for _ in range(5):
        a = rng.uniform(-4, 4, 3)
        want = rot_z(a[2]) @ rot_y(a[1]) @ rot_x(a[0])
        np.testing.assert_allclose(rpy_matrix(a), want, atol=1e-12)
        np.testing.assert_allclose(np.asarray(rpy_matrix(jnp.asarray(a, jnp.float32))), want, atol=1e-6)
        ax = rng.normal(size=3)
        ax /= np.linalg.norm(ax)
        np.testing.assert_allclose(axis_angle_matrix(ax, a[0]), rot_axis(ax, a[0]), atol=1e-12)
    # hand-checked: yaw 90 deg turns +x into +y, pitch 90 deg turns +x into -z, roll 90 deg +y into +z
    np.testing.assert_allclose(rpy_matrix(np.array([0, 0, np.pi / 2])) @ [1, 0, 0], [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(rpy_matrix(np.array([0, np.pi / 2, 0])) @ [1, 0, 0], [0, 0, -1], atol=1e-12)
    np.testing.assert_allclose(rpy_matrix(np.array([np.pi / 2, 0, 0])) @ [0, 1, 0], [0, 0, 1], atol=1e-12)


def test_single_link_by_hand():
    skel = build_skeleton("one", [LinkSpec("a", offset=(0.1, 0, 0), rest=(0, 0, 90), length=0.5, radius=0.02)])
    pose = rest_pose(skel, root_t=(1.0, 2.0, 3.0), scale=2.0)
    out = fk_jit(skel, pose)
    np.testing.assert_allclose(out.origin[0], [1.2, 2.0, 3.0], atol=1e-6)
    np.testing.assert_allclose(out.start[0], [1.2, 2.0, 3.0], atol=1e-6)
    np.testing.assert_allclose(out.end[0], [1.2, 3.0, 3.0], atol=1e-6)  # rest yaw 90: +x -> +y, 2 * 0.5
    np.testing.assert_allclose(out.radius[0], 0.04, atol=1e-7)


def test_slide_joint_by_hand():
    """A slide moves its link (and everything below it) along its axis in the rest frame, times the scale."""
    skel = build_skeleton("slider", [
        LinkSpec("base", joint="fixed", length=0.2),
        LinkSpec("carriage", parent="base", joint="slide", rest=(0, 0, 90), axis=(1, 0, 0), limits=[[-0.1, 0.3]],
                 length=0.1),
        LinkSpec("tip", parent="carriage", joint="fixed", length=0.05),
    ])
    assert skel.num_dof == 7 + 1 and skel.layout.names[-1] == "carriage.q0"
    np.testing.assert_allclose([skel.angle_lo[1, 0], skel.angle_hi[1, 0]], [-0.1, 0.3], atol=1e-7)  # metres
    pose = rest_pose(skel, scale=2.0)
    pose = pose._replace(angles=pose.angles.at[1, 0].set(0.25))
    out = fk_jit(skel, pose)
    # base tip at x = 0.4 (scaled); the carriage's rest yaw 90 turns its axis +x into +y: 2 * 0.25 along y
    np.testing.assert_allclose(out.origin[1], [0.4, 0.5, 0.0], atol=1e-6)
    np.testing.assert_allclose(out.end[1], [0.4, 0.7, 0.0], atol=1e-6)  # the link points along +y, 2 * 0.1
    np.testing.assert_allclose(out.origin[2], [0.4, 0.7, 0.0], atol=1e-6)  # the child moves with it
    np.testing.assert_allclose(np.asarray(out.R_world_link[1]) @ [1, 0, 0], [0, 1, 0], atol=1e-6)  # no rotation from q
    with pytest.raises(SkeletonError, match="slide joint needs 'limits'"):
        build_skeleton("bad", [LinkSpec("a", joint="slide", axis=(1, 0, 0))])
    with pytest.raises(SkeletonError, match="slide axis must be a non-zero vector"):
        build_skeleton("bad", [LinkSpec("a", joint="slide", axis=(0, 0, 0), limits=[[0, 1]])])


# --------------------------------------------------------------------------- against the oracle


@pytest.mark.parametrize("name", ["spider", "humanoid", "arm7", "snake"])
def test_shipped_skeletons_match_oracle(name):
    assert name in shipped_skeletons()
    skel = load_skeleton(name)
    desc = raw_links(name)
    rng = np.random.default_rng(sum(map(ord, name)))
    for _ in range(4):
        assert_matches_oracle(skel, desc, random_pose(skel, rng))
    # and at rest, with the file's lengths
    assert_matches_oracle(skel, desc, rest_pose(skel, root_t=(0.1, -0.2, 2.0), root_rpy=(0.3, -0.2, 1.0)))


def random_tree(rng, L, p_root=0.2, chain_bias=0.0):
    """A random link description: random parents, joints, offsets, attachments, axes,
    rest rotations and capsule placement; returned in shuffled file order."""
    desc = []
    for i in range(L):
        d = dict(name=f"n{i}", joint=str(rng.choice(["ball", "hinge", "slide", "fixed"])))
        if d["joint"] == "slide":
            d["limits"] = [[-0.5, 0.5]]
        if i > 0 and rng.random() > p_root:
            d["parent"] = f"n{i - 1}" if rng.random() < chain_bias else f"n{rng.integers(0, i)}"
        d["offset"] = tuple(rng.normal(0, 0.1, 3))
        if rng.random() < 0.7:
            d["attach"] = float(rng.uniform(0, 1))
        d["rest"] = tuple(rng.uniform(-180, 180, 3))
        d["axis"] = tuple(rng.normal(size=3) + 1e-3)
        d["length"] = float(rng.uniform(0.05, 0.4))
        d["radius"] = float(rng.uniform(0, 0.05))
        if rng.random() < 0.5:
            d["seg_start"] = tuple(rng.normal(0, 0.05, 3))
            d["seg_dir"] = tuple(rng.normal(size=3) + 1e-3)
        desc.append(d)
    order = rng.permutation(L)
    return [desc[k] for k in order]


def build_from_desc(desc, **kw):
    specs = [LinkSpec(**{k: v for k, v in d.items()}) for d in desc]
    return build_skeleton("random", specs, **kw)


@pytest.mark.parametrize("seed", range(6))
def test_random_trees_match_oracle(seed):
    rng = np.random.default_rng(100 + seed)
    desc = random_tree(rng, int(rng.integers(1, 12)))
    skel = build_from_desc(desc)
    assert all(p < i for i, p in enumerate(skel.parents))  # topological order
    for _ in range(2):
        assert_matches_oracle(skel, desc, random_pose(skel, rng, scale=rng.uniform(0.3, 3.0)))


def test_deep_random_tree_matches_oracle():
    """A long chain (many levels of one link each, scanned like any other tree)."""
    rng = np.random.default_rng(7)
    desc = random_tree(rng, 40, p_root=0.02, chain_bias=0.85)
    skel = build_from_desc(desc)
    assert len(skel.levels) > 16
    pose = random_pose(skel, rng, angle_range=0.5, scale=0.7)
    pose = pose._replace(lengths=pose.lengths * 0.2)
    assert_matches_oracle(skel, desc, pose)


@pytest.mark.parametrize("name", ["humanoid", "spider"])
def test_shipped_skeletons_match_oracle_under_a_population_vmap(name):
    """The population form (vmapped over poses, as the search calls it) equals the
    recursive NumPy oracle pose by pose."""
    skel = load_skeleton(name)
    rng = np.random.default_rng(3)
    poses = [random_pose(skel, rng) for _ in range(3)]
    batch = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *poses)
    links = jax.jit(jax.vmap(forward_kinematics, in_axes=(None, 0)))(skel, batch)
    for i, pose in enumerate(poses):
        one = jax.tree_util.tree_map(lambda x: x[i], links)
        assert_matches_oracle(skel, raw_links(name), pose, fk=lambda s, p, one=one: one)


# --------------------------------------------------------------------------- properties


@pytest.fixture(scope="module")
def spider():
    return load_skeleton("spider")


def test_link_lengths_are_preserved_times_scale(spider):
    rng = np.random.default_rng(11)
    for _ in range(3):
        pose = random_pose(spider, rng)
        out = fk_jit(spider, pose)
        got = np.linalg.norm(np.asarray(out.end) - np.asarray(out.start), axis=-1)
        np.testing.assert_allclose(got, float(pose.scale) * np.asarray(pose.lengths), rtol=1e-5)
        # rotations stay orthonormal
        R = np.asarray(out.R_world_link, float)
        np.testing.assert_allclose(R @ np.swapaxes(R, -1, -2), np.broadcast_to(np.eye(3), R.shape), atol=1e-5)
        np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-5)


def test_children_hang_from_their_parents_end(spider):
    """Native links with attach = 1 and no offset start at the parent's far end."""
    pose = random_pose(spider, np.random.default_rng(12))
    out = fk_jit(spider, pose)
    desc = {d["name"]: d for d in raw_links("spider")}
    checked = 0
    for i, p in enumerate(spider.parents):
        name = spider.link_names[i]
        if p >= 0 and "offset" not in desc[name] and "attach" not in desc[name]:
            np.testing.assert_allclose(out.start[i], out.end[p], atol=1e-5)
            checked += 1
    assert checked == 4


def test_root_transform_moves_everything_rigidly(spider):
    rng = np.random.default_rng(13)
    pose = random_pose(spider, rng, root=False)
    base = fk_jit(spider, pose)
    for _ in range(3):
        t, a = rng.uniform(-2, 2, 3), rng.uniform(-3, 3, 3)
        moved = fk_jit(spider, pose._replace(root_t=jnp.asarray(t, jnp.float32), root_rpy=jnp.asarray(a, jnp.float32)))
        R = rpy(*a)
        for key in ("origin", "start", "end"):
            want = np.asarray(getattr(base, key), float) @ R.T + t
            np.testing.assert_allclose(np.asarray(getattr(moved, key)), want, atol=1e-5)
        np.testing.assert_allclose(np.asarray(moved.R_world_link), R @ np.asarray(base.R_world_link, float), atol=1e-5)
        np.testing.assert_allclose(moved.radius, base.radius, atol=0)


def test_vmap_over_population_equals_loop(spider):
    rng = np.random.default_rng(14)
    poses = [random_pose(spider, rng) for _ in range(5)]
    batch = jax.tree.map(lambda *xs: jnp.stack(xs), *poses)
    vm = jax.jit(jax.vmap(forward_kinematics, in_axes=(None, 0)))(spider, batch)
    for k, pose in enumerate(poses):
        for a, b in zip(vm, fk_jit(spider, pose)):
            np.testing.assert_allclose(np.asarray(a[k]), np.asarray(b), atol=1e-6)



def test_deep_chain_of_250_links():
    n = 250
    specs = [LinkSpec("l0", length=0.01, radius=0.001)] + [
        LinkSpec(f"l{i}", parent=f"l{i - 1}", joint="hinge", axis=(0, 0, 1), length=0.01) for i in range(1, n)
    ]
    skel = build_skeleton("deep", specs[::-1])  # children first: the sort must cope
    assert skel.num_links == n and len(skel.levels) == n
    assert skel.num_dof == 7 + 3 + (n - 1)
    pose = rest_pose(skel)
    out = fk_jit(skel, pose)
    np.testing.assert_allclose(out.end[-1], [n * 0.01, 0, 0], atol=1e-4)
    # bend every hinge by the same angle: the chain closes into a regular polygon-ish arc
    q = 2 * np.pi / n
    angles = np.zeros((n, 3), np.float32)
    angles[1:, 0] = q
    out = fk_jit(skel, pose._replace(angles=jnp.asarray(angles)))
    # consecutive segments turn by q about z: all end points lie on one circle (chord 0.01)
    radius = 0.01 / (2 * np.sin(q / 2))
    pts = np.asarray(out.end, float)[:, :2]
    centre = np.array([0.005, radius * np.cos(q / 2)])  # first chord runs from the origin along +x, turning left
    np.testing.assert_allclose(np.linalg.norm(pts - centre, axis=-1), radius, atol=2e-4)
    np.testing.assert_allclose(pts[-1], [0, 0], atol=2e-4)  # a full turn: the polygon closes
