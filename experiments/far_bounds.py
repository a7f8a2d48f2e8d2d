"""Far-capsule bounds: does skipping far capsules make the data term faster?  (Measured; not adopted.)

The kernel (:func:`jaxpose.objective.data_cost`) measures every point against every
capsule.  The idea tested here: order the cloud so that runs of ``tile``
consecutive points are compact (:func:`spatial_order`, a k-d split), bound each
capsule's distance from a whole tile by its distance from the tile's ball, measure
each tile against only the ``near`` capsules with the smallest bounds, and measure
again against every capsule only the (individual, tile) pairs where a capsule
outside those might be nearer (a point's distance so found exceeds the next
bound).  The result is exact (it must equal the kernel's to float round-off; the
script checks).  Whether it saves time depends on how compact the tiles are
against the spacing of the capsules, and on what the selection of the ``near``
capsules costs.

Inputs are real: the populations of a default fit of one data set image (after its
first epoch and at its end, every island: 32 x 64 individuals), scored against
clouds of that image at several ``max_points``.  Both kernels are compiled first,
then timed side by side (median of ``--repeats`` calls); ``fixup share`` is the
fraction of (individual, tile) pairs with points that needed every capsule.

Result: exact, but slower than the kernel (selecting and gathering each tile's
nearest capsules costs more than the distances it saves with 8-17 capsules), so the
search does not use it; measurements in docs/performance.md, "Far-capsule bounds".

Writes ``far_bounds.{json,md}`` (default ``experiments/results``).  Part of ``make bench``.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys
import time
from functools import partial

import common as C
import jax
import jax.numpy as jnp
import numpy as np
from machine import now_iso
from outputs import log, write_json, write_text

from jaxpose.genome import decode
from jaxpose.geometry import TINY_D2
from jaxpose.kinematics import forward_kinematics
from jaxpose.objective import Cloud, ObjectiveConfig, cloud_spread, data_cost, to_blocks
from jaxpose.objective.cloud import present as present_points
from jaxpose.objective.data import link_major, nearest_capsule  # the kernel's own loop, to compare against
from jaxpose.pipeline import load_observation
from jaxpose.search import FitConfig, Fitter

POINTS = (1024, 4096, 16384)
kernel = jax.jit(data_cost)
VARIANTS = ((4, 16), (6, 16), (6, 32), (8, 32))  # (near, tile)
_SLACK = 1e-5  # relative slack on the bounds against float32 round-off
_FIXUP_FRACTION = 8  # (individual, tile) pairs re-measured per pass: 1 / this of all


def spatial_order(cloud: Cloud, tile: int) -> Cloud:
    """The points reordered so that runs of ``tile`` are compact, padding last: sorted
    along the axis of largest extent and halved, as long as the halves stay whole and
    hold at least ``tile`` points; the last groups sorted along their own largest axis."""
    pts, w = present_points(cloud)
    present = w > 0
    n, groups = pts.shape[0], 1
    while n:
        g_pts, g_ok = pts.reshape(groups, n, 3), present.reshape(groups, n)
        lo = jnp.min(jnp.where(g_ok[..., None], g_pts, jnp.inf), 1)
        hi = jnp.max(jnp.where(g_ok[..., None], g_pts, -jnp.inf), 1)
        axis = jnp.argmax(jnp.where(jnp.isfinite(hi - lo), hi - lo, 0.0), -1)
        key = jnp.where(g_ok, jnp.take_along_axis(g_pts, axis[:, None, None], 2)[..., 0], jnp.inf)
        order = (jnp.argsort(key, axis=1, stable=True) + (jnp.arange(groups) * n)[:, None]).reshape(-1)
        pts, w, present = pts[order], w[order], present[order]
        if n % 2 or n // 2 < tile:
            break
        n, groups = n // 2, groups * 2
    return Cloud(pts, w)


def _near_pass(bx, by, bz, bw, links, near: int, tile: int):
    """Each tile against its ``near`` capsules of smallest bound: the distances found
    ``(P, T, tile)``, the next capsule's bound ``(P, T)`` and which points are weighted ``(T, tile)``."""
    pts = jnp.stack([bx, by, bz], -1).reshape(-1, tile, 3)
    present = (bw > 0).reshape(-1, tile)
    centre = jnp.sum(jnp.where(present[..., None], pts, 0.0), 1) / jnp.maximum(jnp.sum(present, 1), 1)[:, None]
    rho = jnp.sqrt(jnp.max(jnp.where(present, jnp.sum((pts - centre[:, None]) ** 2, -1), 0.0), 1))
    a, u, iv, cab, r = (jnp.moveaxis(x, 0, 1) for x in links)  # (P, L, ...)
    L = a.shape[1]
    t = jnp.clip((jnp.einsum("tc,plc->ptl", centre, u) - cab[:, None]) * iv[:, None], 0.0, 1.0)
    diff = centre[None, :, None] - a[:, None] - t[..., None] * u[:, None]
    dist = jnp.sqrt(jnp.sum(diff * diff, -1))  # tile centres to capsule axes (P, T, L)
    rr, rh = r[:, None], rho[None, :, None]
    bound = jnp.maximum(jnp.maximum(dist - rr, rr - dist) - rh - _SLACK * (dist + rr + rh), 0.0)
    # the near smallest bounds by repeated minimum, faster than top_k or an insertion
    # network here (docs/performance.md, "Far-capsule bounds")
    picked, ids = [], jnp.arange(L)
    for _ in range(near):
        i = jnp.argmin(bound, -1)
        picked.append(i)
        bound = jnp.where(ids == i[..., None], jnp.inf, bound)
    cand, next_bound = jnp.stack(picked, -1), jnp.min(bound, -1)
    take = jax.vmap(lambda x, i: x[i])
    A, U, IV, CA, R = (take(x, cand) for x in (a, u, iv, cab, r))  # (P, T, near, ...)
    px, py, pz = (x.reshape(-1, tile) for x in (bx, by, bz))
    best = jnp.full(A.shape[:2] + (tile,), jnp.inf, bx.dtype)
    for j in range(near):  # the kernel's arithmetic, one capsule per (individual, tile)
        ux, uy, uz = U[:, :, j, 0:1], U[:, :, j, 1:2], U[:, :, j, 2:3]
        tj = jnp.clip((px * ux + py * uy + pz * uz - CA[:, :, j, None]) * IV[:, :, j, None], 0.0, 1.0)
        dx, dy, dz = px - A[:, :, j, 0:1] - tj * ux, py - A[:, :, j, 1:2] - tj * uy, pz - A[:, :, j, 2:3] - tj * uz
        d = jnp.abs(jnp.sqrt(jnp.maximum(dx * dx + dy * dy + dz * dz, TINY_D2)) - R[:, :, j, None])
        best = jnp.minimum(best, d)
    return best, next_bound, present


def _bounded_block(bx, by, bz, bw, links, near: int, tile: int):
    """Nearest capsule surface of every (individual, point) of one block, ``(P, B)``,
    exact for the weighted points."""
    best, next_bound, present = _near_pass(bx, by, bz, bw, links, near, tile)
    P, T = best.shape[:2]
    pending = _pending(best, next_bound, present)
    px, py, pz = (x.reshape(T, tile) for x in (bx, by, bz))
    cap = max(1, -(-P * T // _FIXUP_FRACTION))

    def fix(carry):
        pending, best = carry
        flat = pending.reshape(-1)
        (idx,) = jnp.nonzero(flat, size=cap, fill_value=P * T)
        i = jnp.minimum(idx, P * T - 1)
        who, where = i // T, i % T
        d, _ = nearest_capsule(px[where], py[where], pz[where], *(x[:, who] for x in links), with_arg=False)
        best = best.reshape(P * T, tile).at[idx].set(d, mode="drop").reshape(P, T, tile)
        return flat.at[idx].set(False, mode="drop").reshape(P, T), best

    _, best = jax.lax.while_loop(lambda c: jnp.any(c[0]), fix, (pending, best))
    return best.reshape(P, T * tile)


def _blocks(cloud: Cloud, block: int):
    return to_blocks(*present_points(cloud), block)


def _pending(best, next_bound, present):
    """(individual, tile) pairs where a capsule outside the candidates might be nearer."""
    return jnp.any((best > next_bound[..., None]) & present, -1)


@partial(jax.jit, static_argnames=("near", "tile", "block"))
def bounded_cost(cloud: Cloud, sigma, start, end, radius, near: int, tile: int, block: int = 256):
    """The data term with far-capsule bounds (same value as ``data_cost``)."""
    px, py, pz, wb = _blocks(cloud, block)
    links = link_major(start, end, radius)

    def one(total, xs):
        best = _bounded_block(*xs, links, near, tile)
        return total + jnp.sum(xs[3] * jnp.log1p(best / sigma), -1), None

    total, _ = jax.lax.scan(one, jnp.zeros(start.shape[0], start.dtype), (px, py, pz, wb))
    return total / jnp.maximum(jnp.sum(wb), 1e-12)


@partial(jax.jit, static_argnames=("near", "tile", "block"))
def fixup_share(cloud: Cloud, start, end, radius, near: int, tile: int, block: int = 256):
    """Fraction of (individual, tile) pairs with weighted points that need every capsule."""
    links = link_major(start, end, radius)

    def one(acc, xs):
        best, next_bound, present = _near_pass(*xs, links, near, tile)
        pend = _pending(best, next_bound, present)
        used = jnp.broadcast_to(jnp.any(present, -1), pend.shape)
        return (acc[0] + jnp.sum(pend), acc[1] + jnp.sum(used)), None

    (p, n), _ = jax.lax.scan(one, (0, 0), _blocks(cloud, block))
    return p / jnp.maximum(n, 1)


def populations(ds, entry, seed: int):
    """Posed capsules ``(start, end, radius)`` of a default fit's whole population after
    its first epoch and at its last full epoch."""
    skel = ds.skeleton
    fitter = Fitter(skel, FitConfig())
    full = [n for n in fitter.epoch_lengths if n == fitter.config.epoch]
    st = fitter.init(C.load_image(ds, entry).cloud, jax.random.key(seed))

    def posed(st):
        g = st.algo_state.population.reshape(-1, st.algo_state.population.shape[-1])
        links = jax.vmap(lambda x: forward_kinematics(skel, decode(skel, st.bounds, x)))(g)
        return links.start, links.end, links.radius

    out, generation = [], 0
    for k, length in enumerate(full):
        st, _ = fitter.step(st, length)
        generation += length
        if k in (0, len(full) - 1):
            out.append((generation, posed(st)))
    return out


def median_ms(fn, repeats: int) -> float:
    jax.block_until_ready(fn())
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - t)
    return 1e3 * float(np.median(times))


def parse_args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", nargs="+", default=list(C.MODELS), choices=C.MODELS)
    ap.add_argument("--points", nargs="+", type=int, default=list(POINTS), help="max_points of the clouds")
    ap.add_argument("--variants", nargs="+", default=[f"{n}/{t}" for n, t in VARIANTS],
                    help="near/tile pairs (capsules measured first per tile / points per tile)")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--data", default=C.DATA_DIR, help="data folder (default data/; made if missing)")
    ap.add_argument("--out", default=C.RESULTS_DIR)
    a = ap.parse_args(argv)
    try:
        a.variants = [tuple(int(x) for x in v.split("/")) for v in a.variants]
    except ValueError:
        ap.error("--variants takes near/tile pairs such as 6/16")
    if min(a.points) < 1 or a.repeats < 1 or any(len(v) != 2 or min(v) < 1 or 256 % v[1] for v in a.variants):
        ap.error("--points and --repeats must be >= 1; near >= 1 and tile a divisor of 256 (the block)")
    return a


def main(argv=None) -> int:
    a = parse_args(argv)
    C.ensure_data(a.models, a.data)
    rows = []
    for model in a.models:
        ds = C.load_dataset(model, a.data)
        entry = C.select_images(ds, 1)[0]
        log(f"{model}: the populations of a default fit of {entry['name']} ...")
        pops = populations(ds, entry, a.seed)
        for n in a.points:
            opts = dataclasses.replace(C.depth_options(ds, entry), max_points=n)
            cloud = load_observation(os.path.join(ds.folder, entry["image"]), opts)[2]
            sig = cloud_spread(cloud) * ObjectiveConfig().sigma_factor  # as observe() sets it
            for generation, (s, e, r) in pops:
                ref = kernel(cloud, sig, s, e, r)
                t_kernel = median_ms(partial(kernel, cloud, sig, s, e, r), a.repeats)
                for near, tile in a.variants:
                    ordered = spatial_order(cloud, tile)
                    got = bounded_cost(ordered, sig, s, e, r, near, tile)
                    t = median_ms(partial(bounded_cost, ordered, sig, s, e, r, near, tile), a.repeats)
                    row = {"model": model, "links": len(ds.skeleton.link_names), "max_points": n,
                           "points": int(cloud.points.shape[0]), "population": int(s.shape[0]),
                           "generation": generation, "near": near, "tile": tile,
                           "kernel_ms": t_kernel, "bounded_ms": t, "speedup": t_kernel / t,
                           "fixup_share": float(fixup_share(ordered, s, e, r, near, tile)),
                           "max_rel_diff": float(jnp.max(jnp.abs(got - ref) / jnp.abs(ref)))}
                    rows.append(row)
                    log(f"{model:9s} N {n:6d} gen {generation:3d} near {near} tile {tile:3d}: kernel "
                          f"{t_kernel:8.1f} ms, bounded {t:8.1f} ms ({row['speedup']:.2f}x), fix-up "
                          f"{100 * row['fixup_share']:.0f}%, rel diff {row['max_rel_diff']:.1e}")
    out = {"rows": rows, "machine": C.machine_info(), "finished": now_iso()}
    write_json(os.path.join(a.out, "far_bounds.json"), out)
    lines = [("| model (links) | points | generation | near / tile | kernel ms | bounded ms | speed-up | fix-up share "
              "| max rel diff |"), "|---|---:|---:|---|---:|---:|---:|---:|---:|"]
    lines += [f"| {r['model']} ({r['links']}) | {r['points']} | {r['generation']} | {r['near']} / {r['tile']} | "
              f"{r['kernel_ms']:.1f} | {r['bounded_ms']:.1f} | {r['speedup']:.2f}x | {100 * r['fixup_share']:.0f}% | "
              f"{r['max_rel_diff']:.1e} |" for r in rows]
    text = "\n".join(lines) + "\n"
    write_text(os.path.join(a.out, "far_bounds.md"), text)
    print(text)
    bad = [r for r in rows if not r["max_rel_diff"] <= 1e-5]
    if bad:
        print(f"{len(bad)} configurations disagree with the kernel by more than 1e-5", file=sys.stderr)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
