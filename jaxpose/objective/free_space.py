"""The free-space term: model points in front of the observed surface, or outside the
silhouette, would have been seen (see :mod:`jaxpose.objective`)."""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from .cloud import Cloud


class FreeSpaceMap(NamedTuple):
    """A coarse depth map of the cloud over normalised image coordinates ``x/z, y/z``."""

    depth: jax.Array  # (G, G) nearest observed depth per cell (+inf: no data)
    lo: jax.Array  # (2,) lower corner in (x/z, y/z)
    cell: jax.Array  # (2,) cell size


def free_space_map(cloud: Cloud, grid: int = 40) -> FreeSpaceMap:
    """Project the cloud (camera at the origin, looking along +z) to a ``grid^2`` map.

    Each cell keeps the nearest observed depth; the map is then min-filtered over
    3x3 cells so that the gaps of a subsampled cloud do not read as free space.
    """
    pts, w = cloud.points, cloud.weights
    valid = (w > 0) & (pts[:, 2] > 1e-6)
    z = jnp.where(valid, pts[:, 2], 1.0)
    uv = pts[:, :2] / z[:, None]
    big = 1e9
    lo = jnp.min(jnp.where(valid[:, None], uv, big), 0)
    hi = jnp.max(jnp.where(valid[:, None], uv, -big), 0)
    span = jnp.maximum(hi - lo, 1e-3)
    lo = lo - 0.25 * span
    cell = 1.5 * span / grid
    ij = jnp.clip(jnp.floor((uv - lo) / cell).astype(jnp.int32), 0, grid - 1)
    depth = jnp.full((grid, grid), jnp.inf, pts.dtype)
    depth = depth.at[ij[:, 1], ij[:, 0]].min(jnp.where(valid, pts[:, 2], jnp.inf))
    padded = jnp.pad(depth, 1, constant_values=jnp.inf)
    shifted = [padded[1 + di : 1 + di + grid, 1 + dj : 1 + dj + grid] for di in (-1, 0, 1) for dj in (-1, 0, 1)]
    depth = jnp.min(jnp.stack(shifted), 0)
    return FreeSpaceMap(depth, lo, cell)


def free_space_cost(fmap: FreeSpaceMap, sigma, start, end, samples: int, radius=None,
                    max_range: float | None = None) -> jax.Array:
    """Mean free-space penalty of capsule-axis samples, ``start, end (P, L, 3)`` -> ``(P,)``.

    A sample's depth is that of the capsule's front surface, ``z - radius``
    (``radius`` ``(L,)`` or ``(P, L)``; omitted: 0), so that a fat capsule cannot hide
    its axis behind the observed surface while its front bulges out of it.
    ``max_range``: the sensor measures nothing deeper, so a sample deeper than it where
    nothing was observed costs nothing (it would not have been seen); ``None``: no limit.
    """
    grid = fmap.depth.shape[0]
    t = (jnp.arange(samples, dtype=start.dtype) + 0.5) / samples
    pts = start[..., None, :] + t[:, None] * (end - start)[..., None, :]  # (P, L, S, 3)
    z = pts[..., 2]
    in_front_of_camera = z > 1e-3
    uv = pts[..., :2] / jnp.where(in_front_of_camera, z, 1.0)[..., None]
    # cell indices tested and clipped as floats: casting a far-off (or non-finite)
    # coordinate to int32 first would overflow
    ij = jnp.floor((uv - fmap.lo) / fmap.cell)
    inside = jnp.all((ij >= 0) & (ij < grid), -1)
    ijc = jnp.clip(jnp.where(inside[..., None], ij, 0), 0, grid - 1).astype(jnp.int32)
    z_obs = fmap.depth[ijc[..., 1], ijc[..., 0]]
    front = z if radius is None else z - jnp.broadcast_to(radius, start.shape[:-1])[..., None]
    gap = jnp.clip(z_obs - front, 0.0, sigma)  # in front of the observed surface
    observed = inside & jnp.isfinite(z_obs) & in_front_of_camera
    gap = jnp.where(observed, gap, sigma)
    if max_range is not None:  # beyond the sensor's range, no measurement is no evidence of free space
        gap = jnp.where(~observed & in_front_of_camera & (front > max_range), 0.0, gap)
    pen = jnp.log1p(gap / sigma)
    return jnp.mean(pen.reshape(pen.shape[0], -1), -1)
