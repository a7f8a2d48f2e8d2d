"""The paper's objective (equation 1) and the optional free-space term.

Data term, for a cloud of points ``p_n`` with weights ``w_n`` (padding has weight 0)::

    E_data = sum_n w_n ln(1 + d_n / sigma) / sum_n w_n
    d_n    = min_l | dist(p_n, segment_l) - r_l |

``d_n`` is the distance from ``p_n`` to the closest capsule *surface* (a point
inside a capsule is as far from the model as it is from that capsule's wall; with
``r_l = 0`` this is the distance to the segment, as in the paper).

``sigma`` (:func:`cloud_spread`) is the root-mean-square distance of the weighted
points from their weighted centroid, ``sqrt(sum_n w_n ||p_n - c||^2 / sum_n w_n)``:
our reading of the paper's "standard deviation of point distances".  A fixed value
can be given instead (``ObjectiveConfig.sigma``).

Free-space term (not in the paper; ``free_space_weight`` 0 disables it).  The data
term only asks that every observed point be near the model, so a link may float
in empty space at no cost.  For a cloud seen from a camera at the origin looking
along +z, every model point must lie *on or behind* the observed surface: a point
in front of the surface, or outside the silhouette, would have been seen.  The
term samples ``free_space_samples`` points along every capsule axis and charges
``ln(1 + min(gap, sigma) / sigma)`` for a point ``gap`` metres in front of the
observed surface (``ln 2`` outside the silhouette), averaged over the samples.
The observed surface is a coarse depth map of the cloud (:class:`FreeSpaceMap`).

Collision term (not in the paper; ``collision_weight`` 0 disables it).
Neither term above stops a limb the camera cannot see from lying inside the trunk,
where it costs nothing.  A body's parts do not interpenetrate, so for pairs of
capsules ``(i, j)`` the term charges ``sum_k ln(1 + max(0, c_k - d_k) / sigma)``,
``d_k`` the distance between the two axes and ``c_k = rho_k collision_margin
(r_i + r_j)`` the clearance they must keep.  The pairs are every two links but a
link and its parent.  ``rho_k`` in ``[0, 1]`` is the pair's distance in the rest
pose over its clearance (at most 1): a pair that overlaps in the rest pose (a
forearm resting on a thigh, parts designed to overlap) only has to stay as far
apart as it is there, and two links that start at one joint (``rho = 0``) are
never charged (:func:`jaxpose.kinematics.collision_pairs`).  The rest pose is
taken at the skeleton's own lengths (see the README for what that means when
lengths are searched).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

_EPS = 1e-12
# Floor of a squared point-to-axis distance under the square root: keeps the gradient
# finite on the axis without biasing distances (a floor of 1e-12 m^2 made every
# distance at least 1 micrometre, which is not small next to sigma at tiny scales).
_TINY_D2 = 1e-30


class Cloud(NamedTuple):
    """A fixed-size point cloud: ``points (N, 3)`` in metres and ``weights (N,)``.

    Padding points have weight 0; every function treats them as absent.
    """

    points: jax.Array
    weights: jax.Array


@dataclass(frozen=True)
class ObjectiveConfig:
    """Static settings of the cost (hashable, so usable as a jit static argument)."""

    sigma: float | None = None  # None: cloud_spread(cloud)
    sigma_factor: float = 0.25  # multiplies the spread (1: the paper's sigma)
    free_space_weight: float = 1.0
    free_space_samples: int = 6
    free_space_grid: int = 40
    collision_weight: float = 0.1
    collision_margin: float = 0.8  # clearance of two capsules' axes, a fraction of r_i + r_j
    block: int = 256  # points per streamed block in the kernel


def _present(cloud: Cloud):
    """Points with the padding (weight 0) zeroed, so that whatever coordinates the
    padding holds (even NaN) cannot leak into sums as ``0 * nan``."""
    w = cloud.weights
    return jnp.where((w > 0)[:, None], cloud.points, 0.0), w


def cloud_spread(cloud: Cloud) -> jax.Array:
    """sigma: RMS distance of the weighted points from their weighted centroid."""
    pts, w = _present(cloud)
    wsum = jnp.maximum(jnp.sum(w), _EPS)
    c = jnp.sum(pts * w[:, None], 0) / wsum
    d2 = jnp.sum((pts - c) ** 2, -1)
    return jnp.sqrt(jnp.maximum(jnp.sum(w * d2) / wsum, _EPS))


def cloud_centre(cloud: Cloud) -> jax.Array:
    pts, w = _present(cloud)
    return jnp.sum(pts * w[:, None], 0) / jnp.maximum(jnp.sum(w), _EPS)


def point_capsule_distance(points, start, end, radius):
    """Brute-force distances ``(N, L)`` from points to capsule surfaces (reference form)."""
    ab = end - start
    ap = points[:, None, :] - start[None]
    t = jnp.clip(jnp.sum(ap * ab, -1) / jnp.maximum(jnp.sum(ab * ab, -1), _EPS), 0.0, 1.0)
    diff = ap - t[..., None] * ab
    return jnp.abs(jnp.sqrt(jnp.maximum(jnp.sum(diff * diff, -1), _TINY_D2)) - radius)


# Links per unrolled group of the nearest-capsule loop.  Within a group the running
# minimum stays in registers (one fused loop over the block's elements); groups are
# scanned, so the program size stays bounded for long chains.  On a 2-core CPU
# (P=1024, N=2048, L=17) this was 2.8x faster than a scan over single links, whose
# running minimum went through memory at every link.
LINK_GROUP = 24


def _link_scan(bx, by, bz, start, ab, inv, a_ab, radius, with_arg: bool = True):
    """Nearest capsule of every (individual, point) of one block: ``(d, index)``, both ``(P, B)``.

    ``start, ab (L, P, 3)``, ``inv, a_ab, radius (L, P)`` are link-major; the points
    ``bx, by, bz`` are ``(B,)`` (the same for every individual) or ``(P, B)`` (one
    row each).  Links are visited in order with a running minimum (a strictly closer
    link wins, so ties keep the first).  ``with_arg=False`` skips the index
    (returned as ``None``).
    """
    L = start.shape[0]
    G = min(L, LINK_GROUP)
    n_groups = -(-L // G)
    pad = n_groups * G - L
    if pad:  # repeat the last link: never strictly closer than itself, so nothing changes
        start, ab, inv, a_ab, radius = (jnp.concatenate([x, jnp.repeat(x[-1:], pad, 0)]) for x in
                                        (start, ab, inv, a_ab, radius))

    def group(carry, lk):
        best, arg, k0 = carry
        a, u, iv, c, r = lk  # (G, P, 3), (G, P, 3), (G, P), (G, P), (G, P)
        for j in range(G):
            ux, uy, uz = u[j, :, 0:1], u[j, :, 1:2], u[j, :, 2:3]
            t = jnp.clip((bx * ux + by * uy + bz * uz - c[j, :, None]) * iv[j, :, None], 0.0, 1.0)
            dx = bx - a[j, :, 0:1] - t * ux
            dy = by - a[j, :, 1:2] - t * uy
            dz = bz - a[j, :, 2:3] - t * uz
            d = jnp.abs(jnp.sqrt(jnp.maximum(dx * dx + dy * dy + dz * dz, _TINY_D2)) - r[j, :, None])
            closer = d < best
            best = jnp.where(closer, d, best)
            if with_arg:
                arg = jnp.where(closer, k0 + j, arg)
        return (best, arg, k0 + G), None

    P, B = start.shape[1], bx.shape[-1]
    init = (jnp.full((P, B), jnp.inf, bx.dtype), jnp.zeros((P, B), jnp.int32) if with_arg else None, jnp.int32(0))
    grouped = tuple(x.reshape((n_groups, G) + x.shape[1:]) for x in (start, ab, inv, a_ab, radius))
    if n_groups == 1:
        (best, arg, _), _ = group(init, tuple(x[0] for x in grouped))
    else:
        (best, arg, _), _ = jax.lax.scan(group, init, grouped)
    return best, arg


def _point_terms(bx, by, bz, bw, a, b, r, inv_sigma):
    """``sum_b w_b ln(1 + d_pb * inv_sigma)`` for capsules gathered per point: ``a, b (P, B, 3)``, ``r (P, B)``.

    The same arithmetic as :func:`_link_scan`, written for one capsule per point so
    that its derivatives are those of the nearest capsule.
    """
    ab = b - a
    inv = 1.0 / jnp.maximum(jnp.sum(ab * ab, -1), _EPS)
    px = jnp.stack(jnp.broadcast_arrays(bx[None], by[None], bz[None]), -1)  # (1, B, 3)
    t = jnp.clip((jnp.sum(px * ab, -1) - jnp.sum(a * ab, -1)) * inv, 0.0, 1.0)
    diff = px - a - t[..., None] * ab
    d = jnp.abs(jnp.sqrt(jnp.maximum(jnp.sum(diff * diff, -1), _TINY_D2)) - r)
    return jnp.sum(bw * jnp.log1p(d * inv_sigma), -1)


def _prepare(start, end, radius):
    ab = end - start
    inv = 1.0 / jnp.maximum(jnp.sum(ab * ab, -1), _EPS)  # (P, L)
    a_ab = jnp.sum(start * ab, -1)  # (P, L)
    # link-major (L, P, ...) so the scan walks over links
    return jnp.moveaxis(start, -2, 0), jnp.moveaxis(ab, -2, 0), inv.T, a_ab.T, jnp.moveaxis(radius, -1, 0)


def _blocked_scan(px, py, pz, wb, start, end, radius, inv_sigma, with_arg: bool):
    """Sum over blocks of ``w ln(1 + d / sigma)`` with each point's nearest capsule:
    ``(P,)``, and the nearest capsules' indices ``(blocks, P, B)`` (``None`` unless
    ``with_arg``)."""
    links = _prepare(start, end, radius)

    def block(total, xs):
        bx, by, bz, bw = xs
        best, arg = _link_scan(bx, by, bz, *links, with_arg=with_arg)
        return total + jnp.sum(bw * jnp.log1p(best * inv_sigma), -1), arg

    return jax.lax.scan(block, jnp.zeros(start.shape[0], start.dtype), (px, py, pz, wb))


@jax.custom_vjp
def _blocked_sum(px, py, pz, wb, start, end, radius, inv_sigma):
    """``(P,)``: sum over blocks of :func:`_point_terms` with each point's nearest capsule."""
    return _blocked_scan(px, py, pz, wb, start, end, radius, inv_sigma, with_arg=False)[0]


def _blocked_sum_fwd(px, py, pz, wb, start, end, radius, inv_sigma):
    """The value, keeping every point's nearest capsule (``P x N`` indices, not ``P x N x L``)."""
    total, arg = _blocked_scan(px, py, pz, wb, start, end, radius, inv_sigma, with_arg=True)
    return total, (px, py, pz, wb, start, end, radius, inv_sigma, arg)


def _blocked_sum_bwd(res, g):
    """Reverse mode through the nearest capsule only: gather that capsule per point
    (found by the forward pass), differentiate :func:`_point_terms`, and scatter back
    with a one-hot product."""
    px, py, pz, wb, start, end, radius, inv_sigma, args = res
    L = start.shape[1]
    take = jax.vmap(lambda x, i: x[i])  # (P, L, ...) gathered by (P, B) indices

    def block(acc, xs):
        bx, by, bz, bw, arg = xs
        a, b, r = take(start, arg), take(end, arg), take(radius, arg)
        _, vjp = jax.vjp(_point_terms, bx, by, bz, bw, a, b, r, inv_sigma)
        gx, gy, gz, gw, ga, gb, gr, gs = vjp(g)
        onehot = jax.nn.one_hot(arg, L, dtype=start.dtype)  # (P, B, L)
        acc = (
            acc[0] + jnp.einsum("pbl,pbc->plc", onehot, ga),
            acc[1] + jnp.einsum("pbl,pbc->plc", onehot, gb),
            acc[2] + jnp.einsum("pbl,pb->pl", onehot, gr),
            acc[3] + gs,
        )
        return acc, (gx, gy, gz, gw)

    zero = (jnp.zeros_like(start), jnp.zeros_like(end), jnp.zeros_like(radius), jnp.zeros_like(inv_sigma))
    (g_start, g_end, g_radius, g_inv), (gx, gy, gz, gw) = jax.lax.scan(block, zero, (px, py, pz, wb, args))
    return gx, gy, gz, gw, g_start, g_end, g_radius, g_inv


_blocked_sum.defvjp(_blocked_sum_fwd, _blocked_sum_bwd)


def spread_order(n: int) -> np.ndarray:
    """A permutation of ``0 .. n-1`` whose every prefix is spread evenly through the
    original order (a Weyl sequence: ``i`` sorted by ``frac(i / golden ratio)``).  A cloud
    read off an image row by row keeps, in any prefix, points from the whole image."""
    return np.argsort((np.arange(n) * 0.6180339887498949) % 1.0, kind="stable")


def num_blocks(n_points: int, block: int) -> int:
    """Blocks of ``block`` points that :func:`data_cost` splits ``n_points`` into."""
    return -(-n_points // int(max(1, min(block, n_points)))) if n_points else 0


def data_cost(cloud: Cloud, sigma, start, end, radius, block: int = ObjectiveConfig.block, blocks=None) -> jax.Array:
    """The paper's data term for a population: ``start, end (P, L, 3)``, ``radius (P, L)``.

    Streams over blocks of points (outer scan) and over links (unrolled groups of
    :data:`LINK_GROUP`) with a running minimum, on separate coordinate arrays, so memory is
    ``O(P * L + P * block)``: no ``P x N x L`` array is ever formed.  Returns ``(P,)``.
    Reverse-mode derivatives (custom VJP) flow through each point's nearest capsule
    only: the forward pass keeps its index (``P x N`` integers), never per-link residuals.

    ``blocks`` (a traced integer allowed): score only that many blocks of points, taken
    in :func:`spread_order` so that they cover the whole cloud, and average over them
    (coarse-to-fine search: one compiled program serves every count).  Forward only:
    no reverse-mode derivative through a dynamic count.
    """
    pts, w = _present(cloud)
    N = pts.shape[0]
    B = int(max(1, min(block, N)))  # N = 0 (an empty cloud) costs 0
    nb = num_blocks(N, B)
    if blocks is not None:
        order = spread_order(N)
        pts, w = pts[order], w[order]
    px, py, pz, wb = to_blocks(pts, w, B)
    P, L = start.shape[0], start.shape[1]
    radius = jnp.broadcast_to(jnp.asarray(radius, start.dtype), (P, L))
    inv_sigma = (1.0 / jnp.asarray(sigma, start.dtype)).astype(start.dtype)
    if blocks is None:
        total = _blocked_sum(px, py, pz, wb, start, end, radius, inv_sigma)
        return total / jnp.maximum(jnp.sum(w), _EPS)
    total = _prefix_sum(px, py, pz, wb, start, end, radius, inv_sigma, blocks)
    used = jnp.sum(jnp.where(jnp.arange(nb) < blocks, jnp.sum(wb, 1), 0.0))
    return total / jnp.maximum(used, _EPS)


def to_blocks(pts, w, block: int):
    """Coordinate and weight arrays ``(blocks, block)`` of points ``(N, 3)`` and weights
    ``(N,)``, padded with weight-0 points at the origin to whole blocks."""
    N = pts.shape[0]
    nb = num_blocks(N, block)
    pad = nb * block - N
    if pad:
        pts = jnp.concatenate([pts, jnp.zeros((pad, 3), pts.dtype)])
        w = jnp.concatenate([w, jnp.zeros((pad,), w.dtype)])
    return tuple(pts[:, k].reshape(nb, block) for k in range(3)) + (w.reshape(nb, block),)


def _prefix_sum(px, py, pz, wb, start, end, radius, inv_sigma, blocks):
    """:func:`_blocked_scan`'s sum over the first ``blocks`` blocks only (a dynamic count)."""
    links = _prepare(start, end, radius)

    def block(i, total):
        bx, by, bz, bw = (jax.lax.dynamic_index_in_dim(a, i, keepdims=False) for a in (px, py, pz, wb))
        best, _ = _link_scan(bx, by, bz, *links, with_arg=False)
        return total + jnp.sum(bw * jnp.log1p(best * inv_sigma), -1)

    return jax.lax.fori_loop(0, jnp.minimum(blocks, px.shape[0]), block, jnp.zeros(start.shape[0], start.dtype))


# --------------------------------------------------------------------------- free space


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


def free_space_cost(fmap: FreeSpaceMap, sigma, start, end, samples: int, radius=None) -> jax.Array:
    """Mean free-space penalty of capsule-axis samples, ``start, end (P, L, 3)`` -> ``(P,)``.

    A sample's depth is that of the capsule's front surface, ``z - radius``
    (``radius`` ``(L,)`` or ``(P, L)``; omitted: 0), so that a fat capsule cannot hide
    its axis behind the observed surface while its front bulges out of it.
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
    gap = jnp.where(inside & jnp.isfinite(z_obs) & in_front_of_camera, gap, sigma)
    pen = jnp.log1p(gap / sigma)
    return jnp.mean(pen.reshape(pen.shape[0], -1), -1)


# --------------------------------------------------------------------------- collisions


def segment_distance(p1, q1, p2, q2, axis: int = -1) -> jax.Array:
    """Distance between the segments ``p1-q1`` and ``p2-q2`` (coordinates along ``axis``,
    3 of them; the other axes broadcast).

    The closest points by clamped parameters (Ericson, *Real-Time Collision Detection*,
    5.1.9), written branch-free; a segment of length zero is a point.  Computed on
    separate coordinate arrays (a reduction over a minor axis of 3 is slow on CPU).
    """
    p1, q1, p2, q2 = jnp.broadcast_arrays(p1, q1, p2, q2)
    if p1.shape[axis] != 3:
        raise ValueError(f"segment_distance: expected 3 coordinates along axis {axis}, got shape {p1.shape}")
    return _closest_points(*(jnp.moveaxis(v, axis, 0) for v in (p1, q1, p2, q2)))[0]


def _dot3(u, v):
    return u[0] * v[0] + u[1] * v[1] + u[2] * v[2]


def _closest_points(p1, q1, p2, q2):
    """:func:`segment_distance` on coordinate-first arrays ``(3, ...)``: the distance,
    the closest points' parameters ``s`` on ``p1-q1`` and ``t`` on ``p2-q2`` (in
    ``[0, 1]``), and ``diff (3, ...)``, the vector between the closest points."""
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a, e, f, c, b = _dot3(d1, d1), _dot3(d2, d2), _dot3(d2, r), _dot3(d1, r), _dot3(d1, d2)
    a_ok, e_ok = a > _EPS, e > _EPS
    a_s, e_s = jnp.where(a_ok, a, 1.0), jnp.where(e_ok, e, 1.0)
    den = a * e - b * b
    den_ok = den > _EPS * jnp.maximum(a * e, _EPS)
    s = jnp.where(den_ok, jnp.clip((b * f - c * e) / jnp.where(den_ok, den, 1.0), 0.0, 1.0), 0.0)
    t = (b * s + f) / e_s
    s = jnp.where(t < 0, jnp.clip(-c / a_s, 0.0, 1.0), jnp.where(t > 1, jnp.clip((b - c) / a_s, 0.0, 1.0), s))
    t = jnp.clip(t, 0.0, 1.0)
    # degenerate segments: a point against a segment, or two points
    s = jnp.where(a_ok, jnp.where(e_ok, s, jnp.clip(-c / a_s, 0.0, 1.0)), 0.0)
    t = jnp.where(e_ok, jnp.where(a_ok, t, jnp.clip(f / e_s, 0.0, 1.0)), 0.0)
    diff = r + s * d1 - t * d2
    return jnp.sqrt(jnp.maximum(_dot3(diff, diff), _TINY_D2)), s, t, diff


class CollisionPairs(NamedTuple):
    """Capsule pairs the collision term checks: link indices ``i, j`` (static NumPy
    ``(K,)``) and ``rho (K,)``, the fraction of the clearance each pair must keep."""

    i: np.ndarray
    j: np.ndarray
    rho: jax.Array


def collision_cost(pairs: CollisionPairs, sigma, start, end, radius, margin: float) -> jax.Array:
    """Collision penalty ``(P,)`` of posed capsules ``start, end (P, L, 3)``, ``radius (P, L)``
    (see the module docstring).

    Reverse-mode derivatives come from a custom VJP: the distance of two segments
    changes with their ends as the distance of their closest points does (the
    closest points' parameters are a minimum, so their own change does not count),
    and the pairs' gradients go back to the links by products with constant 0/1
    matrices.  Same values as differentiating the arithmetic (to round-off), and a
    smaller program to compile than the backward pass of every clamp and gather.
    Reverse mode only (``jax.grad``, ``jax.vjp``): forward-mode derivatives
    (``jax.jvp``, ``jax.jacfwd``, ``jax.hessian``) of the term raise.  ``sigma`` and
    ``margin`` are scalars or one per individual ``(P,)``.
    """
    if len(pairs.i) == 0:  # (population_cost leaves the term out then)
        return jnp.zeros(start.shape[:1], start.dtype)
    # link-major coordinates (3, L, P): the pairs' gathers pick whole rows
    s, e = jnp.transpose(start, (2, 1, 0)), jnp.transpose(end, (2, 1, 0))
    r = jnp.broadcast_to(jnp.asarray(radius, start.dtype), start.shape[:-1]).T
    i, j = (k if isinstance(k, (np.ndarray, jax.Array)) else np.asarray(k, np.int32) for k in (pairs.i, pairs.j))
    penalty = _pair_penalty(i, j, start.shape[1], start.dtype)
    return penalty(s, e, r, jnp.asarray(pairs.rho, start.dtype), jnp.asarray(sigma, start.dtype),
                   jnp.asarray(margin, start.dtype))


def _pair_penalty(i, j, L: int, dtype):
    """``penalty(s, e (3, L, P), r (L, P), rho (K,), sigma, margin) -> (P,)`` for the
    pairs ``i, j (K,)`` (static or traced)."""
    to_i = (jnp.arange(L)[:, None] == i[None, :]).astype(dtype)  # (L, K): pair k -> link i[k]
    to_j = (jnp.arange(L)[:, None] == j[None, :]).astype(dtype)

    def forward(s, e, r, rho, sigma, margin):
        d, u, v, diff = _closest_points(s[:, i], e[:, i], s[:, j], e[:, j])  # (K, P), (3, K, P)
        reach = rho[:, None] * (r[i] + r[j])
        h = jnp.maximum(margin * reach - d, 0.0)
        return jnp.sum(jnp.log1p(h / sigma), 0), (d, u, v, diff, h, reach, rho, r, sigma, margin)

    def backward(res, g):
        d, u, v, diff, h, reach, rho, r, sigma, margin = res
        dh = jnp.where(margin * reach > d, g / (sigma + h), 0.0)  # d penalty / d clearance, (K, P)
        n = diff * (-dh / d)  # d penalty / d (closest point on i)
        links = lambda M, x: jnp.einsum("lk,...kp->...lp", M, x)  # noqa: E731
        g_s = links(to_i, n * (1.0 - u)) - links(to_j, n * (1.0 - v))
        g_e = links(to_i, n * u) - links(to_j, n * v)
        g_r = links(to_i + to_j, dh * rho[:, None] * margin)
        g_rho = jnp.sum(dh * margin * (r[i] + r[j]), 1)
        g_sigma = -g * jnp.sum(h / (sigma * (sigma + h)), 0)  # (P,)
        return g_s, g_e, g_r, g_rho, _sum_to(g_sigma, sigma.shape), _sum_to(jnp.sum(dh * reach, 0), margin.shape)

    penalty = jax.custom_vjp(lambda *a: forward(*a)[0])
    penalty.defvjp(forward, backward)
    return penalty


def _sum_to(x, shape):
    """``x (P,)`` summed to a scalar argument's ``shape`` (``()``), or kept for one per individual."""
    return x.reshape(shape) if x.shape == tuple(shape) else jnp.sum(x).reshape(shape)


# --------------------------------------------------------------------------- total


class Observation(NamedTuple):
    """Everything the cost needs about one cloud, computed once per fit."""

    cloud: Cloud
    sigma: jax.Array
    fmap: FreeSpaceMap


def observe(cloud: Cloud, config: ObjectiveConfig = ObjectiveConfig()) -> Observation:
    """The cloud, its sigma and its free-space map.  sigma is ``config.sigma`` when given
    (used as it is), else ``cloud_spread(cloud) * config.sigma_factor``."""
    if config.sigma is None:
        sigma = cloud_spread(cloud) * config.sigma_factor
    else:
        sigma = jnp.asarray(config.sigma, jnp.float32)
    return Observation(cloud, sigma, free_space_map(cloud, config.free_space_grid))


def population_cost(obs: Observation, start, end, radius, config: ObjectiveConfig = ObjectiveConfig(), blocks=None,
                    pairs: CollisionPairs | None = None):
    """Total cost ``(P,)`` of a population of posed capsules ``(P, L, 3)`` (``blocks``:
    the data term on that many blocks of points only, see :func:`data_cost`).  The
    collision term needs the skeleton's ``pairs`` (:func:`jaxpose.kinematics.collision_pairs`);
    without them it is left out."""
    cost = data_cost(obs.cloud, obs.sigma, start, end, radius, config.block, blocks)
    if config.free_space_weight > 0:
        cost = cost + config.free_space_weight * free_space_cost(
            obs.fmap, obs.sigma, start, end, config.free_space_samples, radius
        )
    if config.collision_weight > 0 and pairs is not None and len(pairs.i):
        cost = cost + config.collision_weight * collision_cost(pairs, obs.sigma, start, end, radius,
                                                               config.collision_margin)
    return cost


def paper_cost(points, weights, start, end, radius, sigma=None) -> jax.Array:
    """Equation 1 for one posed model ``start, end (L, 3)``; a convenience wrapper."""
    cloud = Cloud(jnp.asarray(points, jnp.float32), jnp.asarray(weights, jnp.float32))
    s = cloud_spread(cloud) if sigma is None else sigma
    return data_cost(cloud, s, start[None], end[None], jnp.broadcast_to(radius, start.shape[:1])[None])[0]

