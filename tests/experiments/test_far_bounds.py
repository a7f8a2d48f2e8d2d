"""The far-capsule-bounds variant of the data term (experiments/far_bounds.py, measured
and not adopted) must compute the paper's cost exactly: its timings mean nothing otherwise.
Oracle: the double-loop NumPy cost of tests/oracles.py."""

from __future__ import annotations

import far_bounds
import jax.numpy as jnp
import numpy as np
import pytest
from oracles import brute_cost

from jaxpose.objective import Cloud


def _scene(seed, N, P, L):
    """Points in a few clusters (compact tiles exist) and capsules near and far from them."""
    rng = np.random.default_rng(seed)
    centres = rng.normal(0, 1.0, (4, 3))
    pts = centres[rng.integers(0, 4, N)] + rng.normal(0, 0.15, (N, 3))
    w = np.where(rng.random(N) < 0.15, 0.0, rng.uniform(0.5, 2.0, N))  # padding scattered through
    start = rng.normal(0, 1.2, (P, L, 3))
    end = start + rng.normal(0, 0.4, (P, L, 3))
    radius = rng.uniform(0.0, 0.2, (P, L))
    return [np.asarray(x, np.float32) for x in (pts, w, start, end, radius)]


@pytest.mark.parametrize("N,P,L,near,tile", [(300, 6, 9, 3, 16), (1000, 5, 17, 6, 32), (64, 4, 30, 4, 8)])
def test_bounded_cost_equals_brute_force(N, P, L, near, tile):
    pts, w, start, end, radius = _scene(N + L, N, P, L)
    sigma = 0.3
    cloud = far_bounds.spatial_order(Cloud(jnp.asarray(pts), jnp.asarray(w)), tile)
    got = np.asarray(far_bounds.bounded_cost(cloud, jnp.float32(sigma), start, end, radius, near, tile))
    want = np.array([brute_cost(pts, w, start[p], end[p], radius[p], sigma) for p in range(P)])
    np.testing.assert_allclose(got, want, rtol=2e-6)
    # the exact fix-up was exercised: some (individual, tile) pairs needed every capsule
    assert float(far_bounds.fixup_share(cloud, start, end, radius, near, tile)) > 0


def test_spatial_order_is_a_permutation_with_padding_last():
    pts, w, *_ = _scene(1, 500, 1, 1)
    out = far_bounds.spatial_order(Cloud(jnp.asarray(pts), jnp.asarray(w)), 16)
    op, ow = np.asarray(out.points), np.asarray(out.weights)
    n = int(np.sum(w > 0))
    assert np.all(ow[:n] > 0) and np.all(ow[n:] == 0)
    key = lambda p, q: np.lexsort(np.c_[p, q].T)
    np.testing.assert_array_equal(np.c_[op, ow][key(op[:n], ow[:n])], np.c_[pts, w][w > 0][key(pts[w > 0], w[w > 0])])
