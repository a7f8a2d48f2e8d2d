"""The cloud the cost reads: fixed-size points with weights (padding has weight 0), its spread and centre."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

EPS = 1e-12


class Cloud(NamedTuple):
    """A fixed-size point cloud: ``points (N, 3)`` in metres and ``weights (N,)``.

    Padding points have weight 0; every function treats them as absent.
    """

    points: jax.Array
    weights: jax.Array


def present(cloud: Cloud):
    """Points with the padding (weight 0) zeroed, so that whatever coordinates the
    padding holds (even NaN) cannot leak into sums as ``0 * nan``."""
    w = cloud.weights
    return jnp.where((w > 0)[:, None], cloud.points, 0.0), w


def cloud_spread(cloud: Cloud) -> jax.Array:
    """sigma: RMS distance of the weighted points from their weighted centroid."""
    pts, w = present(cloud)
    wsum = jnp.maximum(jnp.sum(w), EPS)
    c = jnp.sum(pts * w[:, None], 0) / wsum
    d2 = jnp.sum((pts - c) ** 2, -1)
    return jnp.sqrt(jnp.maximum(jnp.sum(w * d2) / wsum, EPS))


def cloud_centre(cloud: Cloud) -> jax.Array:
    pts, w = present(cloud)
    return jnp.sum(pts * w[:, None], 0) / jnp.maximum(jnp.sum(w), EPS)
