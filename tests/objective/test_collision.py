"""The collision term against double loops in NumPy (tests/oracles.py)."""

from __future__ import annotations

import os
import tomllib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxpose.io.skeleton_file import load_skeleton
from jaxpose.kinematics import collision_pairs, forward_kinematics
from jaxpose.geometry import segment_distance
from jaxpose.objective import ObjectiveConfig, collision_cost, observe, population_cost
from jaxpose.skeleton import Pose, rest_pose
from jaxpose.objective import Cloud

from oracles import collision_penalty, fk_oracle, pose_dict, segment_segment_distance, stack_fk

SKELETON_DIR = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))), "skeletons")
seg_jit = jax.jit(segment_distance)


def f32(x):
    return jnp.asarray(x, jnp.float32)


def special_segments():
    """Parallel, collinear, crossing, touching, end-to-end and degenerate (point) cases."""
    x, y, z = np.eye(3)
    o = np.zeros(3)
    return [
        (o, x, y, x + y),  # parallel, 1 apart
        (o, x, 2 * x, 3 * x),  # collinear, disjoint
        (o, 2 * x, x, 3 * x),  # collinear, overlapping
        (-x, x, -y + 0.5 * z, y + 0.5 * z),  # crossing at 0.5
        (-x, x, -y, y),  # intersecting
        (o, x, x + y, x + 2 * y),  # end to end, 1 apart
        (o, o, x, x + y),  # a point and a segment
        (x + y, x + 2 * y, o, o),  # a segment and a point
        (o, o, z, z),  # two points
        (o, x, 0.5 * x + 0.3 * z, 0.5 * x + 0.3 * z),  # a point above the middle
        (o, x, o + 1e-7 * y, x + 1e-7 * y),  # almost coincident
    ]


def test_segment_distance_matches_ternary_search():
    rng = np.random.default_rng(0)
    cases = special_segments()
    for _ in range(200):
        p1, p2 = rng.normal(0, 1, (2, 3))
        cases.append((p1, p1 + rng.normal(0, 1, 3), p2, p2 + rng.normal(0, 1, 3)))
    p1, q1, p2, q2 = (np.array(c) for c in zip(*cases))
    got = np.asarray(seg_jit(f32(p1), f32(q1), f32(p2), f32(q2)))
    want = np.array([segment_segment_distance(*c) for c in cases])
    np.testing.assert_allclose(got, want, atol=2e-6, rtol=1e-5)
    # symmetric in the two segments and in each segment's direction
    np.testing.assert_allclose(np.asarray(seg_jit(f32(q2), f32(p2), f32(q1), f32(p1))), want, atol=2e-6, rtol=1e-5)


def test_segment_distance_gradient_is_finite_where_segments_meet():
    x, y = np.eye(3)[:2]
    grad = jax.grad(lambda a: segment_distance(a, a + f32(x), f32(-y), f32(y)))
    for a in ([-0.5, 0.0, 0.0], [0.0, 0.0, 0.0], [0.3, 0.2, 0.0]):  # crossing, end on the other, beside it
        assert np.all(np.isfinite(np.asarray(grad(f32(a)))))
    g = grad(f32([-0.5, 0.0, 0.5]))  # 0.5 above the crossing: d/da = the unit normal
    np.testing.assert_allclose(np.asarray(g), [0, 0, 1], atol=1e-5)


def test_segment_distance_broadcasts_before_picking_coordinates():
    rng = np.random.default_rng(2)
    p1, q1 = rng.normal(0, 1, (2, 5, 3))
    p2, q2 = rng.normal(0, 1, (2, 3))  # one segment against five
    want = np.array([segment_segment_distance(a, b, p2, q2) for a, b in zip(p1, q1)])
    got = seg_jit(f32(p1), f32(q1), f32(p2), f32(q2))
    np.testing.assert_allclose(np.asarray(got), want, atol=2e-6, rtol=1e-5)
    got0 = segment_distance(f32(p1.T), f32(q1.T), f32(p2[:, None]), f32(q2[:, None]), axis=0)  # coordinates first
    np.testing.assert_allclose(np.asarray(got0), want, atol=2e-6, rtol=1e-5)
    with pytest.raises(ValueError, match="3 coordinates"):
        segment_distance(jnp.zeros(4), jnp.ones(4), jnp.zeros(4), jnp.ones(4))


def raw_links(name):
    with open(os.path.join(SKELETON_DIR, f"{name}.toml"), "rb") as f:
        return tomllib.load(f)["link"]


def random_poses(skel, rng, P):
    L = skel.num_links
    return Pose(
        root_t=f32(rng.normal([0, 0, 2.5], 0.1, (P, 3))),
        root_rpy=f32(rng.uniform(-np.pi, np.pi, (P, 3))),
        scale=f32(rng.uniform(0.7, 1.3, P)),
        angles=f32(rng.uniform(skel.angle_lo, skel.angle_hi, (P, L, 3))),
        lengths=f32(np.asarray(skel.length) * rng.uniform(0.8, 1.2, (P, L))),
    )


@pytest.mark.parametrize("name,posed", [("humanoid", True), ("spider", False), ("arm7", False)])
def test_collision_cost_matches_double_loop(name, posed):
    """Posed by forward kinematics (random poses within the limits), or capsules
    crowded at random (thin links rarely meet in random poses)."""
    skel = load_skeleton(name)
    desc = raw_links(name)
    rest = stack_fk(fk_oracle(desc, pose_dict(skel, rest_pose(skel))), skel.link_names)
    rng = np.random.default_rng(3)
    P, L, margin, sigma = 6, skel.num_links, 0.8, 0.1
    if posed:
        links = jax.vmap(forward_kinematics, in_axes=(None, 0))(skel, random_poses(skel, rng, P))
        start, end, radius = links.start, links.end, links.radius
    else:
        start = f32(rng.normal([0, 0, 2], 0.05, (P, L, 3)))
        end = start + f32(rng.normal(0, 0.1, (P, L, 3)))
        radius = f32(np.asarray(skel.radius) * rng.uniform(0.7, 1.3, (P, 1)))
    pairs = jax.jit(collision_pairs, static_argnames="margin")(skel, margin=margin)
    # a link and its parent are never a pair; every other pair is
    pairset = set(zip(pairs.i.tolist(), pairs.j.tolist()))
    assert all((skel.parents[j] != i) for i, j in pairset)
    assert len(pairset) == sum(1 for i in range(L) for j in range(i + 1, L) if skel.parents[j] != i)
    got = np.asarray(jax.jit(collision_cost, static_argnames="margin")(pairs, sigma, start, end, radius, margin=margin))
    want = [collision_penalty(np.asarray(start[k], float), np.asarray(end[k], float), np.asarray(radius[k], float),
                              skel.parents, *rest[2:], margin, sigma)
            for k in range(P)]
    np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-5)
    assert max(want) > 0.05  # the capsules do collide: the comparison is not of zeros


def test_the_rest_pose_costs_nothing_and_a_limb_through_the_trunk_does():
    skel = load_skeleton("humanoid")
    pairs = collision_pairs(skel, 0.8)
    rest = forward_kinematics(skel, rest_pose(skel, root_t=(0, 0, 3.0)))
    cost = lambda lk: float(collision_cost(pairs, 0.1, lk.start[None], lk.end[None], lk.radius[None], 0.8)[0])  # noqa: E731
    # pairs that overlap at rest sit exactly at their clearance there: only round-off is left
    assert cost(rest) < 1e-4
    # the left forearm moved onto the trunk's axis
    i, t = skel.index("l_forearm"), skel.index("upper_spine")
    start = rest.start.at[i].set(rest.start[t])
    end = rest.end.at[i].set(rest.end[t])
    assert cost(rest._replace(start=start, end=end)) > 0.5


def test_population_cost_adds_the_weighted_collision_term_only_with_pairs():
    skel = load_skeleton("humanoid")
    rng = np.random.default_rng(1)
    poses = random_poses(skel, rng, 4)
    links = jax.vmap(forward_kinematics, in_axes=(None, 0))(skel, poses)
    pts = rng.normal([0, 0, 2.5], 0.3, (300, 3))
    obs = observe(Cloud(f32(pts), jnp.ones(300, jnp.float32)))
    pairs = collision_pairs(skel, 0.8)
    base = ObjectiveConfig(collision_weight=0.0)
    with_term = ObjectiveConfig(collision_weight=0.3)
    cost = jax.jit(population_cost, static_argnames="config")
    c0 = np.asarray(cost(obs, links.start, links.end, links.radius, base, pairs=pairs))
    c1 = np.asarray(cost(obs, links.start, links.end, links.radius, with_term, pairs=pairs))
    c2 = np.asarray(cost(obs, links.start, links.end, links.radius, with_term))
    coll = np.asarray(collision_cost(pairs, obs.sigma, links.start, links.end, links.radius, 0.8))
    np.testing.assert_allclose(c1, c0 + 0.3 * coll, rtol=1e-5)
    np.testing.assert_allclose(c2, c0, rtol=0)
    assert coll.max() > 0


def test_skeletons_without_pairs_cost_nothing():
    """One link, or a link and its child: nothing to check (and nothing fails)."""
    from jaxpose.skeleton import LinkSpec, build_skeleton

    for specs in ([LinkSpec("a", None, length=0.3, radius=0.05)],
                  [LinkSpec("a", None, length=0.3, radius=0.05), LinkSpec("b", "a", length=0.3, radius=0.05)]):
        skel = build_skeleton("no_pairs", specs)
        pairs = collision_pairs(skel, 0.8)
        assert len(pairs.i) == len(pairs.j) == 0
        lk = forward_kinematics(skel, rest_pose(skel))
        c = collision_cost(pairs, 0.1, lk.start[None], lk.end[None], lk.radius[None], 0.8)
        assert c.shape == (1,) and float(c[0]) == 0.0


def test_collision_cost_gradient_matches_finite_differences():
    """The custom VJP (closest points held, pairs scattered back by 0/1 products)
    against central differences in float64, for every argument that can carry one:
    capsule ends, radii, sigma, rho and the margin."""
    from jax.test_util import check_grads

    from jaxpose.objective import CollisionPairs

    skel = load_skeleton("spider")
    rng = np.random.default_rng(5)
    P, L = 3, skel.num_links
    with jax.enable_x64(True):
        pairs = collision_pairs(skel, 0.8)
        start = jnp.asarray(rng.normal([0, 0, 2], 0.05, (P, L, 3)))
        end = start + jnp.asarray(rng.normal(0, 0.1, (P, L, 3)))
        radius = jnp.asarray(np.asarray(skel.radius) * rng.uniform(0.7, 1.3, (P, 1)))
        rho = jnp.asarray(rng.uniform(0.5, 1.0, len(pairs.i)))

        def total(sigma, start, end, radius, rho, margin):
            return jnp.sum(collision_cost(CollisionPairs(pairs.i, pairs.j, rho), sigma, start, end, radius, margin)
                           * jnp.arange(1.0, P + 1))

        args = (jnp.asarray(0.1), start, end, radius, rho, jnp.asarray(0.8))
        assert float(total(*args)) > 0.1  # the capsules do collide: the gradient is not of zeros
        check_grads(total, args, order=1, modes=["rev"], eps=1e-6, atol=1e-5, rtol=1e-5)
        # one sigma and one margin per individual
        check_grads(total, (jnp.asarray([0.1, 0.12, 0.08]),) + args[1:5] + (jnp.asarray([0.8, 0.7, 0.9]),),
                    order=1, modes=["rev"], eps=1e-6, atol=1e-5, rtol=1e-5)


def test_collision_pairs_given_as_lists_cost_the_same():
    skel = load_skeleton("spider")
    pairs = collision_pairs(skel, 0.8)
    lk = forward_kinematics(skel, rest_pose(skel))
    start, end = lk.start[None], lk.end[None].at[0, 0].set(lk.start[3])  # one leg bent onto another
    as_lists = pairs._replace(i=pairs.i.tolist(), j=pairs.j.tolist())
    want = collision_cost(pairs, 0.1, start, end, lk.radius[None], 0.8)
    assert float(want[0]) > 0
    np.testing.assert_array_equal(collision_cost(as_lists, 0.1, start, end, lk.radius[None], 0.8), want)
