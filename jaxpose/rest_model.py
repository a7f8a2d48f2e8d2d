"""The rest-pose model's shape: centroid, principal axes and spread at scale 1.

The search starts from it (the initial scale and the orientation hypotheses) and the
file pipeline checks a cloud's size against it; both read it here.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from .kinematics import forward_kinematics
from .skeleton import Skeleton, rest_pose

# An elongated model (major variance at least this many times the second) spins its
# orientation hypotheses about its major axis, a flat one about its normal.
ELONGATED = 2.0


class RestModel(NamedTuple):
    """The rest-pose model's shape at scale 1: centroid, principal axes, RMS spread,
    and the axis that orientation hypotheses spin about."""

    centre: jax.Array  # (3,)
    axes: jax.Array  # (3, 3) columns by decreasing variance
    spread: jax.Array  # ()
    spin_axis: jax.Array  # () int: 0 (the major axis) or 2 (the minor axis)


def model_samples(skel: Skeleton) -> jax.Array:
    """Points along the rest-pose capsule axes at scale 1 (skeleton frame), ``(8 L, 3)``."""
    links = forward_kinematics(skel, rest_pose(skel))
    t = jnp.linspace(0.0, 1.0, 8)[:, None, None]
    return (links.start[None] + t * (links.end - links.start)[None]).reshape(-1, 3)


def principal_axes(points: jax.Array, weights: jax.Array):
    """Weighted centroid ``(3,)``, principal axes (columns, ``(3, 3)``) and variances
    ``(3,)``, by decreasing variance."""
    wsum = jnp.maximum(jnp.sum(weights), 1e-12)
    c = jnp.sum(points * weights[:, None], 0) / wsum
    d = points - c
    cov = (d * weights[:, None]).T @ d / wsum + 1e-9 * jnp.eye(3)
    val, vec = jnp.linalg.eigh(cov)  # ascending eigenvalues
    return c, vec[:, ::-1], val[::-1]


def rest_model(skel: Skeleton) -> RestModel:
    """:class:`RestModel` of ``skel`` (one forward-kinematics pass of the rest pose)."""
    pts = model_samples(skel)
    c, axes, var = principal_axes(pts, jnp.ones(pts.shape[0]))
    spin = jnp.where(var[0] >= ELONGATED * var[1], 0, 2)
    return RestModel(c, axes, jnp.sqrt(jnp.mean(jnp.sum((pts - c) ** 2, -1)) + 1e-12), spin)
