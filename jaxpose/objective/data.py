"""The paper's data term (equation 1): each point's log-robust distance to the nearest
capsule surface, streamed over blocks of points and groups of links, with a custom VJP.
See :mod:`jaxpose.objective` for the formula and docs/performance.md for the kernel's design."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..geometry import TINY_D2
from .cloud import EPS, Cloud, present
from .config import ObjectiveConfig


def point_capsule_distance(points, start, end, radius):
    """Brute-force distances ``(N, L)`` from points to capsule surfaces (reference form)."""
    ab = end - start
    ap = points[:, None, :] - start[None]
    t = jnp.clip(jnp.sum(ap * ab, -1) / jnp.maximum(jnp.sum(ab * ab, -1), EPS), 0.0, 1.0)
    diff = ap - t[..., None] * ab
    return jnp.abs(jnp.sqrt(jnp.maximum(jnp.sum(diff * diff, -1), TINY_D2)) - radius)


# Links per unrolled group of the nearest-capsule loop: the running minimum stays in
# registers within a group; groups are scanned, so long chains compile to bounded
# programs (docs/performance.md, "Unrolled link groups").
LINK_GROUP = 24


def nearest_capsule(bx, by, bz, start, ab, inv, a_ab, radius, with_arg: bool = True):
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
            d = jnp.abs(jnp.sqrt(jnp.maximum(dx * dx + dy * dy + dz * dz, TINY_D2)) - r[j, :, None])
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

    The same arithmetic as :func:`nearest_capsule`, written for one capsule per point so
    that its derivatives are those of the nearest capsule.
    """
    ab = b - a
    inv = 1.0 / jnp.maximum(jnp.sum(ab * ab, -1), EPS)
    px = jnp.stack(jnp.broadcast_arrays(bx[None], by[None], bz[None]), -1)  # (1, B, 3)
    t = jnp.clip((jnp.sum(px * ab, -1) - jnp.sum(a * ab, -1)) * inv, 0.0, 1.0)
    diff = px - a - t[..., None] * ab
    d = jnp.abs(jnp.sqrt(jnp.maximum(jnp.sum(diff * diff, -1), TINY_D2)) - r)
    return jnp.sum(bw * jnp.log1p(d * inv_sigma), -1)


def link_major(start, end, radius):
    """The capsules ``(P, L, ...)`` as :func:`nearest_capsule` reads them: link-major
    ``(start, axis, 1 / |axis|^2, start . axis, radius)``."""
    ab = end - start
    inv = 1.0 / jnp.maximum(jnp.sum(ab * ab, -1), EPS)  # (P, L)
    a_ab = jnp.sum(start * ab, -1)  # (P, L)
    # link-major (L, P, ...) so the scan walks over links
    return jnp.moveaxis(start, -2, 0), jnp.moveaxis(ab, -2, 0), inv.T, a_ab.T, jnp.moveaxis(radius, -1, 0)


def _blocked_scan(px, py, pz, wb, start, end, radius, inv_sigma, with_arg: bool):
    """Sum over blocks of ``w ln(1 + d / sigma)`` with each point's nearest capsule:
    ``(P,)``, and the nearest capsules' indices ``(blocks, P, B)`` (``None`` unless
    ``with_arg``)."""
    links = link_major(start, end, radius)

    def block(total, xs):
        bx, by, bz, bw = xs
        best, arg = nearest_capsule(bx, by, bz, *links, with_arg=with_arg)
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
    pts, w = present(cloud)
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
        return total / jnp.maximum(jnp.sum(w), EPS)
    total = _prefix_sum(px, py, pz, wb, start, end, radius, inv_sigma, blocks)
    used = jnp.sum(jnp.where(jnp.arange(nb) < blocks, jnp.sum(wb, 1), 0.0))
    return total / jnp.maximum(used, EPS)


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
    links = link_major(start, end, radius)

    def block(i, total):
        bx, by, bz, bw = (jax.lax.dynamic_index_in_dim(a, i, keepdims=False) for a in (px, py, pz, wb))
        best, _ = nearest_capsule(bx, by, bz, *links, with_arg=False)
        return total + jnp.sum(bw * jnp.log1p(best * inv_sigma), -1)

    return jax.lax.fori_loop(0, jnp.minimum(blocks, px.shape[0]), block, jnp.zeros(start.shape[0], start.dtype))
