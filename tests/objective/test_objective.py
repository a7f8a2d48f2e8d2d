"""The objective against a brute-force NumPy evaluation of equation 1, and the free-space term."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxpose.objective import (
    Cloud,
    ObjectiveConfig,
    cloud_centre,
    cloud_spread,
    data_cost,
    free_space_cost,
    num_blocks,
    observe,
    paper_cost,
    point_capsule_distance,
    population_cost,
    spread_order,
)

from oracles import brute_cost, spread, surface_distances
from jaxpose.errors import ConfigError

RTOL = 1e-5
data_cost_jit = jax.jit(data_cost, static_argnames="block")
paper_cost_jit = jax.jit(paper_cost)
pop_cost_jit = jax.jit(population_cost, static_argnames="config")
free_space_jit = jax.jit(free_space_cost, static_argnames="samples")


def f32(x):
    return jnp.asarray(x, jnp.float32)


def random_scene(rng, N, L, P, radius_kind):
    """Points around z = 2 m and a population of ``P`` models of ``L`` capsules there."""
    pts = rng.normal([0, 0, 2.0], 0.3, (N, 3))
    start = rng.normal([0, 0, 2.0], 0.3, (P, L, 3))
    end = start + rng.normal(0, 0.2, (P, L, 3))
    if radius_kind == "zero":
        radius = np.zeros((P, L))
    elif radius_kind == "pos":
        radius = rng.uniform(0.01, 0.15, (P, L))
    else:  # mixed, with a zero-length capsule
        radius = rng.uniform(0.0, 0.15, (P, L)) * (rng.random((P, L)) < 0.5)
        end[:, 0] = start[:, 0]
    return pts, start, end, radius


CASES = [  # N, L, block, radii: N = 1, N a multiple of the block, N not a multiple, N < block
    (1, 1, 1024, "zero"),
    (64, 3, 16, "pos"),
    (101, 4, 16, "mixed"),
    (37, 8, 1024, "pos"),
    (300, 2, 128, "zero"),
    (40, 24, 16, "mixed"),  # exactly one unrolled link group (LINK_GROUP)
    (45, 53, 32, "pos"),  # several link groups, the last one padded
]


@pytest.mark.parametrize("N, L, block, radii", CASES)
def test_data_cost_equals_brute_force(N, L, block, radii):
    rng = np.random.default_rng(N * 31 + L)
    P = 3
    pts, start, end, radius = random_scene(rng, N, L, P, radii)
    w = rng.uniform(0.2, 2.0, N)  # fractional weights: a weighted mean
    sigma = 0.17
    got = np.asarray(data_cost_jit(Cloud(f32(pts), f32(w)), f32(sigma), f32(start), f32(end), f32(radius), block=block))
    want = [brute_cost(pts, w, start[k], end[k], radius[k], sigma) for k in range(P)]
    np.testing.assert_allclose(got, want, rtol=RTOL, atol=1e-7)
    # the streamed kernel does not depend on the block size
    other = data_cost_jit(Cloud(f32(pts), f32(w)), f32(sigma), f32(start), f32(end), f32(radius), block=7)
    np.testing.assert_allclose(np.asarray(other), got, rtol=2e-6)


def test_spread_order_prefixes_cover_the_whole_cloud():
    for n in (1, 7, 1024, 1000):
        order = spread_order(n)
        assert sorted(order.tolist()) == list(range(n))
    order = spread_order(1024)
    for k in (64, 256, 512):  # any prefix: no gap in the original order much wider than n / k
        assert np.max(np.diff(np.sort(order[:k]))) <= 3 * 1024 / k


@pytest.mark.parametrize("N, block, blocks", [(101, 16, 2), (101, 16, 7), (64, 16, 4), (64, 16, 9), (37, 1024, 1)])
def test_data_cost_on_leading_blocks_equals_brute_force_on_those_points(N, block, blocks):
    """``blocks=k``: the weighted mean over the first ``k * block`` points in spread order
    (all of them once ``k`` covers the cloud), a traced count serving every ``k``."""
    rng = np.random.default_rng(N + blocks)
    P, L = 3, 4
    pts, start, end, radius = random_scene(rng, N, L, P, "mixed")
    w = rng.uniform(0.2, 2.0, N) * (rng.random(N) < 0.8)  # some padding (weight 0) too
    sigma = 0.17
    fn = jax.jit(data_cost, static_argnames="block")
    got = np.asarray(fn(Cloud(f32(pts), f32(w)), f32(sigma), f32(start), f32(end), f32(radius), block=block,
                        blocks=jnp.int32(blocks)))
    used = spread_order(N)[: blocks * min(block, N)]
    want = [brute_cost(pts[used], w[used], start[k], end[k], radius[k], sigma) for k in range(P)]
    np.testing.assert_allclose(got, want, rtol=RTOL, atol=1e-7)
    assert num_blocks(N, block) == -(-N // min(block, N))


@pytest.mark.parametrize("N, L, radii", [(50, 3, "pos"), (129, 5, "zero")])
def test_paper_cost_uses_cloud_spread_and_equals_brute_force(N, L, radii):
    rng = np.random.default_rng(N)
    pts, start, end, radius = random_scene(rng, N, L, 1, radii)
    w = np.ones(N)
    got = float(paper_cost_jit(pts, w, f32(start[0]), f32(end[0]), f32(radius[0])))
    assert got == pytest.approx(brute_cost(pts, w, start[0], end[0], radius[0]), rel=RTOL)
    got = float(paper_cost_jit(pts, w, f32(start[0]), f32(end[0]), f32(radius[0]), f32(0.05)))
    assert got == pytest.approx(brute_cost(pts, w, start[0], end[0], radius[0], 0.05), rel=RTOL)


def test_cloud_spread_and_centre_equal_weighted_definitions():
    rng = np.random.default_rng(1)
    pts = rng.normal([0.3, -0.1, 2.0], [0.2, 0.4, 0.1], (40, 3))
    w = rng.uniform(0, 3, 40)
    w[::5] = 0
    c = (w[:, None] * pts).sum(0) / w.sum()
    assert float(cloud_spread(Cloud(f32(pts), f32(w)))) == pytest.approx(spread(pts, w), rel=1e-5)
    np.testing.assert_allclose(cloud_centre(Cloud(f32(pts), f32(w))), c, atol=1e-6)
    # sigma is the RMS distance from the centroid: a unit sphere's surface points have sigma 1
    u = rng.normal(size=(200, 3))
    u /= np.linalg.norm(u, axis=-1, keepdims=True)
    assert float(cloud_spread(Cloud(f32(u + 5.0), jnp.ones(200)))) == pytest.approx(1.0, abs=0.01)


def test_point_capsule_distance_reference_form():
    rng = np.random.default_rng(2)
    pts, start, end, radius = random_scene(rng, 30, 4, 1, "mixed")
    got = np.asarray(point_capsule_distance(f32(pts), f32(start[0]), f32(end[0]), f32(radius[0])))
    want = np.stack([surface_distances(pts, start[0][l : l + 1], end[0][l : l + 1], radius[0][l]) for l in range(4)], -1)
    np.testing.assert_allclose(got, want, atol=2e-6)


def test_weight_zero_padding_changes_nothing():
    rng = np.random.default_rng(3)
    pts, start, end, radius = random_scene(rng, 45, 3, 2, "pos")
    w = rng.uniform(0.5, 1.5, 45)
    sigma = cloud_spread(Cloud(f32(pts), f32(w)))
    base = data_cost_jit(Cloud(f32(pts), f32(w)), sigma, f32(start), f32(end), f32(radius), block=16)
    # padding anywhere: far away, at the origin, and (robustness) non-finite
    pad = np.concatenate([rng.normal(0, 100, (20, 3)), np.zeros((5, 3)), np.full((3, 3), np.nan), np.full((2, 3), np.inf)])
    pp = np.concatenate([pts, pad])
    pw = np.concatenate([w, np.zeros(len(pad))])
    perm = rng.permutation(len(pp))  # padding interleaved with the data
    cloud = Cloud(f32(pp[perm]), f32(pw[perm]))
    assert float(cloud_spread(cloud)) == pytest.approx(float(sigma), rel=1e-6)
    padded = data_cost_jit(cloud, cloud_spread(cloud), f32(start), f32(end), f32(radius), block=16)
    np.testing.assert_allclose(np.asarray(padded), np.asarray(base), rtol=2e-6)
    want = [brute_cost(pts, w, start[k], end[k], radius[k]) for k in range(2)]
    np.testing.assert_allclose(np.asarray(padded), want, rtol=RTOL)
    # scaling every weight by a constant changes nothing either
    scaled = data_cost_jit(Cloud(cloud.points, 3.0 * cloud.weights), sigma, f32(start), f32(end), f32(radius), block=16)
    np.testing.assert_allclose(np.asarray(scaled), np.asarray(base), rtol=2e-6)


def test_empty_and_all_padding_clouds_cost_zero():
    start = f32(np.zeros((2, 1, 3)))
    end = f32(np.ones((2, 1, 3)))
    radius = f32(np.zeros((2, 1)))
    empty = data_cost(Cloud(jnp.zeros((0, 3)), jnp.zeros(0)), f32(0.1), start, end, radius)
    np.testing.assert_array_equal(np.asarray(empty), [0.0, 0.0])
    pad = data_cost(Cloud(jnp.ones((4, 3)), jnp.zeros(4)), f32(0.1), start, end, radius)
    np.testing.assert_array_equal(np.asarray(pad), [0.0, 0.0])


def surface_points(rng, a, b, r, n):
    """Points exactly on the capsule surface: the cylinder wall and both hemispherical caps."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    axis = (b - a) / np.linalg.norm(b - a)
    u = np.cross(axis, [1.0, 0, 0] if abs(axis[0]) < 0.9 else [0, 1.0, 0])
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    out = []
    for _ in range(n):
        kind = rng.integers(3)
        if kind == 0:
            phi, t = rng.uniform(0, 2 * np.pi), rng.uniform(0, 1)
            out.append(a + t * (b - a) + r * (np.cos(phi) * u + np.sin(phi) * v))
        else:
            d = rng.normal(size=3)
            d /= np.linalg.norm(d)
            cap, sgn = (a, -1) if kind == 1 else (b, 1)
            if sgn * d @ axis < 0:
                d -= 2 * (d @ axis) * axis  # onto the outer hemisphere
            out.append(cap + r * d)
    return np.array(out)


def test_cost_is_zero_on_the_surface():
    rng = np.random.default_rng(4)
    start = np.array([[0, 0, 2.0], [0.2, 0.1, 2.1], [-0.1, 0.3, 1.9]])
    end = np.array([[0.3, 0, 2.0], [0.2, 0.4, 2.2], [-0.3, 0.3, 2.1]])
    radius = np.array([0.05, 0.03, 0.0])
    pts = np.concatenate([surface_points(rng, start[l], end[l], radius[l], 40) for l in range(3)])
    got = float(paper_cost_jit(pts, np.ones(len(pts)), f32(start), f32(end), f32(radius)))
    assert 0.0 <= got < 2e-5
    # and moving the points off the surface costs
    off = float(paper_cost_jit(pts + [0, 0, 0.05], np.ones(len(pts)), f32(start), f32(end), f32(radius)))
    assert off > 100 * max(got, 1e-6)


# --------------------------------------------------------------------------- population and free space


def plane_cloud(n=30, z=2.0, half=0.5):
    g = np.stack(np.meshgrid(np.linspace(-half, half, n), np.linspace(-half, half, n)), -1).reshape(-1, 2)
    return Cloud(f32(np.concatenate([g, np.full((len(g), 1), z)], 1)), jnp.ones(len(g)))


@pytest.fixture(scope="module")
def plane_obs():
    return jax.jit(observe, static_argnames="config")(plane_cloud(), config=ObjectiveConfig(sigma_factor=1.0))


def fs_cost(obs, start, end, samples=6):
    return float(free_space_jit(obs.fmap, obs.sigma, f32(start)[None], f32(end)[None], samples=samples)[0])


def test_free_space_term(plane_obs):
    """The cloud is a plane at z = 2 (camera at the origin looking along +z)."""
    sigma = float(plane_obs.sigma)
    assert sigma == pytest.approx(spread(np.asarray(plane_obs.cloud.points), np.ones(900)), rel=1e-5)
    # behind the observed surface, inside the silhouette: free
    assert fs_cost(plane_obs, [[-0.2, 0, 2.3], [0.0, -0.2, 2.0]], [[0.2, 0.1, 2.5], [0.1, 0.2, 3.0]]) == 0.0
    # 0.1 m in front of it: ln(1 + 0.1 / sigma) at every sample
    got = fs_cost(plane_obs, [[-0.2, 0, 1.9]], [[0.2, 0.1, 1.9]])
    assert got == pytest.approx(np.log1p(0.1 / sigma), rel=1e-5)
    # far in front: the gap saturates at sigma
    assert fs_cost(plane_obs, [[-0.1, 0, 0.5]], [[0.1, 0, 0.5]]) == pytest.approx(np.log(2), rel=1e-6)
    # half the samples in front (0.1 m), half behind
    got = fs_cost(plane_obs, [[-0.2, 0, 1.9], [-0.2, 0, 2.2]], [[0.2, 0, 1.9], [0.2, 0, 2.2]])
    assert got == pytest.approx(0.5 * np.log1p(0.1 / sigma), rel=1e-5)
    # beside the silhouette (empty cells of the map) and outside the map: ln 2
    assert fs_cost(plane_obs, [[0.8, 0, 2.5]], [[0.85, 0, 2.5]]) == pytest.approx(np.log(2), rel=1e-6)
    assert fs_cost(plane_obs, [[30.0, 0, 2.5]], [[31.0, 0, 2.5]]) == pytest.approx(np.log(2), rel=1e-6)
    assert fs_cost(plane_obs, [[3e3, 0, 1.5e-3]], [[-3e3, 0, 1.2e-3]]) == pytest.approx(np.log(2), rel=1e-6)


def test_beyond_the_sensors_range_no_measurement_is_not_free_space(plane_obs):
    """``max_range``: a sample deeper than the sensor measures, where nothing was observed, costs
    nothing; where something was observed, and within the range, the term is unchanged."""
    def cost(start, end, max_range):
        return float(free_space_cost(plane_obs.fmap, plane_obs.sigma, f32(start)[None], f32(end)[None], 6,
                                     max_range=max_range)[0])

    sigma = float(plane_obs.sigma)
    beside = ([[1.4, 0, 4.5]], [[1.45, 0, 4.5]])  # empty cells of the map (beside the plane), 4.5 m deep
    assert cost(*beside, None) == pytest.approx(np.log(2), rel=1e-6)
    assert cost(*beside, 4.0) == 0.0  # beyond a 4 m sensor: it would not have been seen
    assert cost(*beside, 5.0) == pytest.approx(np.log(2), rel=1e-6)  # within a 5 m one: it would
    # a capsule reaching from 3.5 to 4.5 m beside the silhouette: the samples beyond 4 m (t = 7/12 .. 11/12)
    reach = ([[1.4, 0, 3.5]], [[1.4, 0, 4.5]])
    depths = 3.5 + (np.arange(6) + 0.5) / 6
    assert cost(*reach, 4.0) == pytest.approx(np.mean(np.where(depths > 4.0, 0.0, np.log(2))), rel=1e-6)
    # observed cells and samples in front of the camera's plane keep their cost
    assert cost([[-0.2, 0, 1.9]], [[0.2, 0.1, 1.9]], 1.0) == pytest.approx(np.log1p(0.1 / sigma), rel=1e-5)
    assert cost([[0.8, 0, -4.5]], [[0.85, 0, -4.5]], 4.0) == pytest.approx(np.log(2), rel=1e-6)
    with pytest.raises(ConfigError, match="objective.max_range"):
        ObjectiveConfig(max_range=0.0).validate()
    # population_cost passes the config's range
    cfg = ObjectiveConfig(max_range=4.0, collision_weight=0.0)
    s, e = (f32(a)[None] for a in beside)
    with_range = float(pop_cost_jit(plane_obs, s, e, jnp.zeros((1, 1)), config=cfg)[0])
    without = float(pop_cost_jit(plane_obs, s, e, jnp.zeros((1, 1)), config=ObjectiveConfig(collision_weight=0.0))[0])
    assert without - with_range == pytest.approx(np.log(2), rel=1e-5)


def test_population_cost_is_data_plus_weighted_free_space_per_individual(plane_obs):
    rng = np.random.default_rng(5)
    P, L = 4, 3
    start = rng.normal([0, 0, 2.0], 0.3, (P, L, 3))
    end = start + rng.normal(0, 0.2, (P, L, 3))
    radius = rng.uniform(0.01, 0.05, (P, L))
    pts = np.asarray(plane_obs.cloud.points)
    sigma = float(plane_obs.sigma)
    cfg = ObjectiveConfig(free_space_weight=0.5, block=256)
    for rad in (radius, np.zeros((P, L))):
        pop = np.asarray(pop_cost_jit(plane_obs, f32(start), f32(end), f32(rad), config=cfg))
        for k in range(P):  # each individual scored alone gives the same cost
            one = pop_cost_jit(plane_obs, f32(start[k : k + 1]), f32(end[k : k + 1]), f32(rad[k : k + 1]), config=cfg)
            assert float(one[0]) == pytest.approx(pop[k], rel=2e-6)
    # thin capsules: the brute-force data term plus the weighted free-space term of the axes
    for k in range(P):
        want = brute_cost(pts, np.ones(len(pts)), start[k], end[k], np.zeros(L), sigma) + 0.5 * fs_cost(
            plane_obs, start[k], end[k]
        )
        assert pop[k] == pytest.approx(want, rel=RTOL)
    # free_space_weight 0: the data term alone, radii included
    only = np.asarray(pop_cost_jit(plane_obs, f32(start), f32(end), f32(radius), config=ObjectiveConfig(free_space_weight=0.0)))
    want = [brute_cost(pts, np.ones(len(pts)), start[k], end[k], radius[k], sigma) for k in range(P)]
    np.testing.assert_allclose(only, want, rtol=RTOL)


def test_a_model_lying_on_the_plane_beats_one_floating_in_front(plane_obs):
    # three thin capsules lying in the plane, along the cloud's rows
    ys = np.array([-0.3, 0.0, 0.3])
    start = np.stack([np.full(3, -0.5), ys, np.full(3, 2.0)], -1)
    end = np.stack([np.full(3, 0.5), ys, np.full(3, 2.0)], -1)
    cfg = ObjectiveConfig(block=256)
    on = float(pop_cost_jit(plane_obs, f32(start)[None], f32(end)[None], jnp.zeros((1, 3)), config=cfg)[0])
    floating = float(
        pop_cost_jit(plane_obs, f32(start - [0, 0, 0.2])[None], f32(end - [0, 0, 0.2])[None], jnp.zeros((1, 3)), config=cfg)[0]
    )
    behind = float(
        pop_cost_jit(plane_obs, f32(start + [0, 0, 0.2])[None], f32(end + [0, 0, 0.2])[None], jnp.zeros((1, 3)), config=cfg)[0]
    )
    assert fs_cost(plane_obs, start, end) == 0.0
    assert on < behind < floating  # same data cost behind and in front; only the free-space term differs
    assert floating - behind == pytest.approx(cfg.free_space_weight * np.log1p(0.2 / float(plane_obs.sigma)), rel=1e-4)


# --------------------------------------------------------------------------- gradient (custom VJP)


@pytest.mark.parametrize("N,block,L", [(37, 16, 5), (256, 64, 53)])
def test_data_cost_gradient_matches_autodiff_of_brute_force(N, block, L):
    """The kernel's hand-written reverse mode (nearest capsule only) equals plain
    autodiff of the brute-force (N, L) form, for start, end, radius, sigma and points."""
    from jaxpose.objective import point_capsule_distance

    rng = np.random.default_rng(3)
    P = 3
    pts = f32(rng.normal(size=(N, 3)) * 0.3)
    w = f32(rng.uniform(0.2, 1.0, N))
    start = f32(rng.normal(size=(P, L, 3)) * 0.3)
    end = start + f32(rng.normal(size=(P, L, 3)) * 0.2)
    radius = f32(rng.uniform(0.0, 0.05, (P, L)))

    def kernel(pts, start, end, radius, sigma):
        return jnp.sum(data_cost(Cloud(pts, w), sigma, start, end, radius, block) * jnp.arange(1.0, P + 1))

    def brute(pts, start, end, radius, sigma):
        d = jax.vmap(lambda s, e, r: jnp.min(point_capsule_distance(pts, s, e, r), -1))(start, end, radius)
        c = jnp.sum(w * jnp.log1p(d / sigma), -1) / jnp.sum(w)
        return jnp.sum(c * jnp.arange(1.0, P + 1))

    args = (pts, start, end, radius, jnp.float32(0.2))
    gk = jax.grad(kernel, argnums=range(5))(*args)
    gb = jax.grad(brute, argnums=range(5))(*args)
    for a, b in zip(gk, gb):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=2e-4, atol=1e-6)


def test_observe_sigma_fixed_or_a_fraction_of_the_spread():
    cloud = plane_cloud()
    s = float(cloud_spread(cloud))
    assert float(observe(cloud, ObjectiveConfig(sigma_factor=0.25)).sigma) == pytest.approx(0.25 * s, rel=1e-6)
    assert float(observe(cloud, ObjectiveConfig(sigma_factor=1.0)).sigma) == pytest.approx(s, rel=1e-6)
    # a fixed sigma is used as it is: sigma_factor applies to the cloud's spread only
    assert float(observe(cloud, ObjectiveConfig(sigma=0.1, sigma_factor=0.25)).sigma) == pytest.approx(0.1)


def test_the_link_group_cases_above_cover_one_and_several_groups():
    from jaxpose.objective import LINK_GROUP

    Ls = {L for _, L, _, _ in CASES}
    assert LINK_GROUP in Ls and any(L > LINK_GROUP and L % LINK_GROUP for L in Ls)
