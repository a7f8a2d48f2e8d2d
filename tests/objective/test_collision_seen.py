"""``ObjectiveConfig.collision_seen``: a pair's collision penalty scaled by ``1 - min(seen_i, seen_j)``,
the capsules' fractions of axis samples on the observed surface (``seen_fraction``)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxpose.geometry import segment_distance
from jaxpose.objective import (Cloud, CollisionPairs, ObjectiveConfig, collision_cost, observe, population_cost,
                               seen_fraction)

SIGMA, MARGIN = 0.1, 0.8


def f32(x):
    return jnp.asarray(x, jnp.float32)


def wall(z=3.0, half=1.0, n=60):
    """A flat wall of points facing the camera at depth ``z``, ``2 half`` metres wide."""
    g = np.linspace(-half, half, n)
    x, y = np.meshgrid(g, g)
    pts = np.stack([x.ravel(), y.ravel(), np.full(x.size, z)], -1)
    return observe(Cloud(f32(pts), jnp.ones(len(pts), jnp.float32)))


def test_seen_fraction_of_capsules_on_behind_and_in_front_of_the_surface():
    obs, r = wall(), 0.05
    on = ([-0.4, 0, 3 + r], [0.4, 0, 3 + r])  # lying on the wall: its front surface is the wall
    behind = ([-0.4, 0, 3.5], [0.4, 0, 3.5])  # hidden behind it
    floating = ([-0.4, 0, 2.5], [0.4, 0, 2.5])  # in front of it, where the camera sees nothing
    outside = ([2.5, 0, 3 + r], [3.5, 0, 3 + r])  # beside the wall, off the data
    start, end = f32([[s for s, _ in (on, behind, floating, outside)]]), f32([[e for _, e in (on, behind, floating,
                                                                                                  outside)]])
    seen = np.asarray(seen_fraction(obs.fmap, start, end, 8, f32([[r] * 4])))
    np.testing.assert_array_equal(seen, [[1.0, 0.0, 0.0, 0.0]])
    # half over the wall's edge: about half its samples on data
    half = np.asarray(seen_fraction(obs.fmap, f32([[[0.6, 0, 3 + r]]]), f32([[[1.4, 0, 3 + r]]]), 8, f32([[r]])))
    assert 0.375 <= half[0, 0] <= 0.75


def pair_penalty_oracle(start, end, radius, i, j, rho, scale):
    """Double loop over the pairs, each penalty times its scale."""
    total = 0.0
    for k in range(len(i)):
        d = float(segment_distance(np.asarray(start[i[k]], float), np.asarray(end[i[k]], float),
                                   np.asarray(start[j[k]], float), np.asarray(end[j[k]], float), xp=np))
        total += scale[k] * np.log1p(max(0.0, rho[k] * MARGIN * (radius[i[k]] + radius[j[k]]) - d) / SIGMA)
    return total


def test_scaled_collision_cost_matches_double_loop_and_its_gradient_autodiff():
    rng = np.random.default_rng(0)
    P, L = 3, 6
    i, j = np.array([0, 0, 1, 2, 3], np.int32), np.array([1, 2, 4, 5, 5], np.int32)
    rho = f32(rng.uniform(0.5, 1.0, len(i)))
    pairs = CollisionPairs(i, j, rho)
    start = f32(rng.normal([0, 0, 2], 0.05, (P, L, 3)))
    end = start + f32(rng.normal(0, 0.1, (P, L, 3)))
    radius = f32(rng.uniform(0.04, 0.08, (P, L)))
    scale = f32(rng.uniform(0, 1, (len(i), P)))
    got = np.asarray(collision_cost(pairs, SIGMA, start, end, radius, MARGIN, scale))
    want = [pair_penalty_oracle(np.asarray(start[p]), np.asarray(end[p]), np.asarray(radius[p]), i, j,
                                np.asarray(rho), np.asarray(scale[:, p])) for p in range(P)]
    np.testing.assert_allclose(got, want, rtol=1e-4, atol=1e-6)
    assert max(want) > 0.05  # the capsules do collide
    # the custom VJP against autodiff of the plain arithmetic; no derivative flows into the scale
    weights = jnp.arange(1.0, P + 1)

    def plain(s, e, r):
        d = jax.vmap(lambda a, b, c, dd: segment_distance(a, b, c, dd, xp=jnp))(
            jnp.moveaxis(s[:, i], 1, 0).reshape(-1, 3), jnp.moveaxis(e[:, i], 1, 0).reshape(-1, 3),
            jnp.moveaxis(s[:, j], 1, 0).reshape(-1, 3), jnp.moveaxis(e[:, j], 1, 0).reshape(-1, 3)).reshape(len(i), P)
        h = jnp.maximum(rho[:, None] * MARGIN * (r[:, i] + r[:, j]).T - d, 0.0)
        return jnp.sum(jnp.sum(scale * jnp.log1p(h / SIGMA), 0) * weights)

    def custom(s, e, r, w):
        return jnp.sum(collision_cost(pairs, SIGMA, s, e, r, MARGIN, w) * weights)

    g_custom = jax.grad(custom, (0, 1, 2, 3))(start, end, radius, scale)
    g_plain = jax.grad(plain, (0, 1, 2))(start, end, radius)
    for a, b in zip(g_custom[:3], g_plain):
        np.testing.assert_allclose(a, b, rtol=1e-3, atol=1e-4)
        assert float(jnp.max(jnp.abs(b))) > 0.1
    assert float(jnp.max(jnp.abs(g_custom[3]))) == 0.0


def test_population_cost_frees_pairs_the_camera_sees_and_charges_a_limb_inside_the_trunk():
    obs = wall()
    pairs = CollisionPairs(np.array([0], np.int32), np.array([1], np.int32), f32([1.0]))
    r, fat, thin = 0.05, 0.15, 0.03
    # two capsules side by side on the surface, 5 cm apart (clearance 8 cm)
    seen_pair = (f32([[[-0.4, 0, 3 + r], [-0.4, 0.05, 3 + r]]]), f32([[[0.4, 0, 3 + r], [0.4, 0.05, 3 + r]]]),
                 f32([[r, r]]))
    # a thin limb along the axis of a fat trunk whose front is the surface: hidden inside it
    inside = (f32([[[-0.4, 0, 3 + fat], [-0.3, 0, 3 + fat]]]), f32([[[0.4, 0, 3 + fat], [0.3, 0, 3 + fat]]]),
              f32([[fat, thin]]))
    default, seen_cfg = ObjectiveConfig(), ObjectiveConfig(collision_seen=True)
    cost = jax.jit(population_cost, static_argnames="config")
    for (start, end, radius), freed in ((seen_pair, True), (inside, False)):
        c0 = float(cost(obs, start, end, radius, default, pairs=pairs)[0])
        c1 = float(cost(obs, start, end, radius, seen_cfg, pairs=pairs)[0])
        no_pairs = float(cost(obs, start, end, radius, default)[0])
        assert c0 - no_pairs > 0.01  # the default charges the pair
        if freed:  # both capsules on the surface: the data term holds them, no charge
            np.testing.assert_allclose(c1, no_pairs, rtol=1e-6)
        else:  # the limb's front lies deeper than its diameter behind the surface: charged as by default
            np.testing.assert_allclose(c1, c0, rtol=1e-6)
