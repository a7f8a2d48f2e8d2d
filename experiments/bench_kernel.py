"""The objective's micro-benchmark (``bench.py``): one data term, three implementations.

Throughput is counted in point-to-capsule distance evaluations per second: a call
that scores ``P`` individuals of ``L`` capsules against ``N`` cloud points evaluates
``P * N * L`` distances (``N`` is the cloud's array size, padding included, as in
``FitResult.distance_evaluations``).  The implementations, on the same inputs
(:func:`make_problem`):

- ``kernel``: :func:`jaxpose.objective.data_cost`, jit-compiled (the streaming kernel);
- ``naive_vmap``: ``jax.jit(jax.vmap(per_individual_cost))`` where the per-individual
  cost forms the ``(N, L)`` distance matrix with
  :func:`jaxpose.objective.point_capsule_distance` (so ``(P, N, L)`` under vmap);
- ``numpy``: a loop over individuals, each vectorised over points and links with
  NumPy on ``(N, L)`` coordinate arrays (single core).

:func:`measure_config` compiles and warms each, times the three side by side
(:func:`bench_timing.time_interleaved`) and checks that they agree.
"""

from __future__ import annotations

import math
import time

import jax
import jax.numpy as jnp
import numpy as np
from bench_timing import compile_timed, round_ratios, time_calls, time_interleaved, timing_record
from outputs import fmt, fmt_rate

from jaxpose.objective import Cloud, cloud_spread, data_cost, point_capsule_distance

EPS = 1e-12
TOLERANCE = 1e-5  # the three costs must agree to this relative difference

# links -> skeleton: the shipped spider (8) and humanoid (17), and a generated 40-link chain
# (the shipped snake has only 10 links)
SKELETONS = {8: "spider", 17: "humanoid", 40: "chain40"}
REFERENCE = dict(P=1024, N=2048, L=17)  # the headline configuration


# --------------------------------------------------------------------------- problems


def chain_skeleton(n: int = 40):
    """A generated snake-like chain of ``n`` ball-jointed capsules."""
    from jaxpose.skeleton import LinkSpec, build_skeleton

    links = []
    for i in range(n):
        links.append(LinkSpec(
            name=f"seg{i}", parent=f"seg{i - 1}" if i else None, joint="ball",
            limits=[[-20, 20], [-30, 30], [-30, 30]], length=0.05, length_range=(0.035, 0.065), radius=0.015,
        ))
    return build_skeleton(f"chain{n}", links)


_SKELETON_CACHE: dict = {}


def get_skeleton(name: str):
    if name not in _SKELETON_CACHE:
        if name.startswith("chain"):
            _SKELETON_CACHE[name] = chain_skeleton(int(name[5:]))
        else:
            from jaxpose.io.skeleton_file import load_skeleton

            _SKELETON_CACHE[name] = load_skeleton(name)
    return _SKELETON_CACHE[name]


_FK_CACHE: dict = {}
FK_CHUNK = 256


def posed_capsules(skel, bounds, genomes: np.ndarray):
    """``(start, end, radius)`` of genomes ``(M, D)`` in ``[0, 1]``: decode + FK, in chunks of ``FK_CHUNK``."""
    from jaxpose.genome import decode
    from jaxpose.kinematics import forward_kinematics

    key = skel.name
    if key not in _FK_CACHE:
        def fk(sk, b, g):
            links = jax.vmap(lambda x: forward_kinematics(sk, decode(sk, b, x)))(g)
            return links.start, links.end, links.radius

        _FK_CACHE[key] = jax.jit(fk)
    fk = _FK_CACHE[key]
    M = genomes.shape[0]
    pad = -M % FK_CHUNK
    g = np.concatenate([genomes, np.full((pad, genomes.shape[1]), 0.5, genomes.dtype)]).astype(np.float32)
    outs = [fk(skel, bounds, g[i: i + FK_CHUNK]) for i in range(0, len(g), FK_CHUNK)]
    s, e, r = (np.concatenate([np.asarray(o[k]) for o in outs])[:M] for k in range(3))
    return s.astype(np.float32), e.astype(np.float32), r.astype(np.float32)


def make_problem(L: int, N: int, P: int, seed: int = 0) -> dict:
    """A cloud of ``N`` points (1/16 of them weight-0 padding) sampled on the capsules of one
    random pose ~2 m in front of the camera, and a population of ``P`` random poses of the same
    skeleton around it.  The cost has no data-dependent branches, so only the sizes matter
    for speed; realistic geometry keeps the agreement check meaningful."""
    from jaxpose.genome import genome_bounds, genome_layout

    name = SKELETONS[L]
    skel = get_skeleton(name)
    assert skel.num_links == L, (name, skel.num_links, L)
    rng = np.random.default_rng([seed, L, N, P])
    D = genome_layout(skel).size
    bounds = genome_bounds(skel, np.array([0.0, 0.0, 2.0], np.float32), 0.3)
    truth = posed_capsules(skel, bounds, rng.uniform(0.2, 0.8, (1, D)))
    s, e, r = (a[0].astype(np.float64) for a in truth)
    n_valid = N - N // 16
    ln = np.linalg.norm(e - s, axis=1)
    area = (ln + 2 * r) * np.maximum(r, 1e-3)
    link = rng.choice(L, n_valid, p=area / area.sum())
    u = (e - s)[link] / np.maximum(ln[link], 1e-9)[:, None]
    v = rng.standard_normal((n_valid, 3))
    v -= np.sum(v * u, 1, keepdims=True) * u
    v /= np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-9)
    t = rng.uniform(0, 1, n_valid)[:, None]
    pts = s[link] + t * (e - s)[link] + r[link][:, None] * v + 0.003 * rng.standard_normal((n_valid, 3))
    points = np.zeros((N, 3), np.float32)
    weights = np.zeros(N, np.float32)
    perm = rng.permutation(N)[:n_valid]  # padding scattered through the array, as after subsampling
    points[perm] = pts
    weights[perm] = 1.0
    pop = posed_capsules(skel, bounds, rng.uniform(0, 1, (P, D)))
    sigma = np.float32(cloud_spread(Cloud(jnp.asarray(points), jnp.asarray(weights))))
    return dict(skeleton=name, points=points, weights=weights, sigma=sigma, start=pop[0], end=pop[1], radius=pop[2])


# --------------------------------------------------------------------------- the three implementations


def numpy_cost(points, weights, sigma, start, end, radius, dtype=np.float32) -> np.ndarray:
    """The data term with NumPy, one individual at a time (vectorised over points x links)."""
    pts = np.asarray(points, dtype)
    w = np.asarray(weights, dtype)
    px, py, pz = pts[:, 0:1], pts[:, 1:2], pts[:, 2:3]  # (N, 1)
    wsum = max(float(w.sum()), EPS)
    inv_sigma = dtype(1.0 / float(sigma))
    start, end, radius = (np.asarray(a, dtype) for a in (start, end, radius))
    out = np.empty(start.shape[0], np.float64)
    for i in range(start.shape[0]):
        a, u, r = start[i], end[i] - start[i], radius[i]  # (L, 3), (L, 3), (L,)
        inv = 1.0 / np.maximum(np.sum(u * u, -1), EPS)
        c = np.sum(a * u, -1)
        t = (px * u[:, 0] + py * u[:, 1] + pz * u[:, 2] - c) * inv  # (N, L)
        np.clip(t, 0.0, 1.0, out=t)
        dx = px - a[:, 0] - t * u[:, 0]
        dy = py - a[:, 1] - t * u[:, 1]
        dz = pz - a[:, 2] - t * u[:, 2]
        d = np.abs(np.sqrt(np.maximum(dx * dx + dy * dy + dz * dz, EPS)) - r)
        out[i] = float(np.sum(w * np.log1p(d.min(1) * inv_sigma))) / wsum
    return out


def _naive_one(points, weights, sigma, start, end, radius):
    d = point_capsule_distance(points, start, end, radius)  # (N, L)
    return jnp.sum(weights * jnp.log1p(jnp.min(d, 1) / sigma)) / jnp.maximum(jnp.sum(weights), EPS)


naive_cost = jax.jit(jax.vmap(_naive_one, in_axes=(None, None, None, 0, 0, 0)))


def kernel_fn(block: int):
    return jax.jit(lambda cloud, sigma, s, e, r: data_cost(cloud, sigma, s, e, r, block))


def kernel_grad_fn(block: int):
    """Gradient of the summed kernel cost with respect to the capsule ends (what refinement uses)."""
    return jax.jit(jax.grad(lambda cloud, sigma, s, e, r: jnp.sum(data_cost(cloud, sigma, s, e, r, block)),
                            argnums=(2, 3)))


def kernel_args(pr, n=None):
    sl = slice(None) if n is None else slice(0, n)
    cloud = Cloud(jnp.asarray(pr["points"]), jnp.asarray(pr["weights"]))
    return (cloud, jnp.asarray(pr["sigma"]), jnp.asarray(pr["start"][sl]), jnp.asarray(pr["end"][sl]),
            jnp.asarray(pr["radius"][sl]))


def naive_args(pr, n=None):
    sl = slice(None) if n is None else slice(0, n)
    return (jnp.asarray(pr["points"]), jnp.asarray(pr["weights"]), jnp.asarray(pr["sigma"]),
            jnp.asarray(pr["start"][sl]), jnp.asarray(pr["end"][sl]), jnp.asarray(pr["radius"][sl]))

def rel_diff(a, b) -> float:
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return float(np.max(np.abs(a - b) / np.maximum(np.abs(b), 1e-30)))


def pow2_floor(x: float) -> int:
    return 1 << max(0, int(math.floor(math.log2(max(x, 1)))))


def measure_config(L: int, N: int, P: int, args) -> dict:
    """Time the three implementations on one configuration and check that they agree."""
    pr = make_problem(L, N, P, args.seed)
    dist = P * N * L
    rec = {"skeleton": pr["skeleton"], "L": L, "N": N, "P": P, "distances": dist, "block": args.block}
    mr, Mr, budget = args.min_repeats, args.repeats, args.time_budget

    # (c) the kernel: compiled and warmed here, timed below with the other two
    kargs = kernel_args(pr)
    kernel, c_s, temp = compile_timed(kernel_fn(args.block), kargs)
    t = time.perf_counter()
    k_out = np.asarray(jax.block_until_ready(kernel(*kargs)), np.float64)
    warm = time.perf_counter() - t
    rec["kernel"] = {"compile_s": c_s, "first_call_s": warm, "xla_temp_bytes": temp, "P_measured": P}
    for b in args.blocks or ():
        if b == args.block:
            continue
        cb, cbs, tb = compile_timed(kernel_fn(b), kargs)
        jax.block_until_ready(cb(*kargs))
        tb_times, _ = time_calls(lambda: cb(*kargs), mr, Mr, budget)
        rec.setdefault("kernel_blocks", {})[str(b)] = {"compile_s": cbs, "xla_temp_bytes": tb,
                                                       **timing_record(tb_times, dist)}

    # the kernel's gradient (reverse mode through its scans), on the first --grad-P individuals,
    # at the reference configuration or with --grad
    if args.grad or (L, N, P) == (REFERENCE["L"], REFERENCE["N"], REFERENCE["P"]):
        Pg = min(P, args.grad_P)
        gargs = kernel_args(pr, Pg)
        cg, cg_s, gtemp = compile_timed(kernel_grad_fn(args.block), gargs)
        t = time.perf_counter()
        jax.block_until_ready(cg(*gargs))
        gwarm = time.perf_counter() - t
        g_times, _ = time_calls(lambda: cg(*gargs), mr, Mr, budget)
        g = {"compile_s": cg_s, "first_call_s": gwarm, "xla_temp_bytes": gtemp, "P_measured": Pg, "subset": Pg < P,
             **timing_record(g_times, Pg * N * L)}
        rec["kernel_grad"] = g
        del cg, gargs

    # (b) the naive vmap: full P when its XLA temporaries fit in --naive-max-mb, else fewer individuals
    limit = args.naive_max_mb * 2**20
    nargs = naive_args(pr)
    naive, nc_s, full_temp = compile_timed(naive_cost, nargs)  # compiling does not allocate the scratch
    ntemp = full_temp
    per_ind = (full_temp / P) if full_temp else 8.0 * N * L * 4
    Pn = P if per_ind * P <= limit else min(P, pow2_floor(limit / per_ind))
    if Pn < P:
        nargs = naive_args(pr, Pn)
        naive, nc_s, ntemp = compile_timed(naive_cost, nargs)
    t = time.perf_counter()
    n_out = np.asarray(jax.block_until_ready(naive(*nargs)), np.float64)
    nwarm = time.perf_counter() - t
    rec["naive_vmap"] = {"compile_s": nc_s, "first_call_s": nwarm, "xla_temp_bytes": ntemp,
                         "xla_temp_bytes_full_P": full_temp, "P_measured": Pn, "subset": Pn < P}

    # (a) NumPy: as many individuals as one call of --numpy-seconds / --min-repeats allows
    np_args = (pr["points"], pr["weights"], pr["sigma"])
    t = time.perf_counter()
    numpy_cost(*np_args, pr["start"][:1], pr["end"][:1], pr["radius"][:1])  # warm (page faults, caches)
    t1 = time.perf_counter() - t
    t = time.perf_counter()
    numpy_cost(*np_args, pr["start"][:2], pr["end"][:2], pr["radius"][:2])
    t1 = min(t1, (time.perf_counter() - t) / 2)
    Pnp = int(max(1, min(P, args.numpy_seconds / max(mr, 1) / max(t1, 1e-9))))
    sl = slice(0, Pnp)
    rec["numpy"] = {"dtype": "float32", "P_measured": Pnp, "subset": Pnp < P}

    # the three timed side by side, in rounds (see time_interleaved)
    calls = {"kernel": lambda: kernel(*kargs), "naive_vmap": lambda: naive(*nargs),
             "numpy": lambda: numpy_cost(*np_args, pr["start"][sl], pr["end"][sl], pr["radius"][sl])}
    counts = {"kernel": dist, "naive_vmap": Pn * N * L, "numpy": Pnp * N * L}
    times, outs, rounds = time_interleaved(calls, mr, Mr, 2 * budget + args.numpy_seconds)
    np_out = outs["numpy"]
    for name, tm in times.items():
        rec[name].update(timing_record(tm, counts[name]))
    if "kernel_grad" in rec:
        rec["kernel_grad"]["slowdown_vs_forward"] = rec["kernel"]["evals_per_s"] / rec["kernel_grad"]["evals_per_s"]
    rec["rounds"] = len(rounds)
    rec["ratio_range"] = {f"kernel_vs_{o}": round_ratios(rounds, counts, "kernel", o) for o in ("numpy", "naive_vmap")}

    # agreement: every pair on the individuals both computed; and against float64 NumPy
    n64 = min(P, 4)
    np64 = numpy_cost(*np_args, pr["start"][:n64], pr["end"][:n64], pr["radius"][:n64], dtype=np.float64)
    diffs = {
        "kernel_vs_numpy": rel_diff(k_out[:Pnp], np_out),
        "kernel_vs_naive_vmap": rel_diff(k_out[:Pn], n_out),
        "naive_vmap_vs_numpy": rel_diff(n_out[: min(Pn, Pnp)], np_out[: min(Pn, Pnp)]),
    }
    rec["rel_diff"] = diffs
    rec["max_rel_diff"] = max(diffs.values())
    rec["kernel_rel_err_vs_float64"] = rel_diff(k_out[:n64], np64)
    rec["agree"] = rec["max_rel_diff"] <= TOLERANCE
    nv, nu = rec["naive_vmap"]["evals_per_s"], rec["numpy"]["evals_per_s"]
    # the ratios: medians of the rounds' ratios (each round's three measured side by side)
    rec["kernel_vs_numpy"] = rec["ratio_range"]["kernel_vs_numpy"][1]
    rec["kernel_vs_naive_vmap"] = rec["ratio_range"]["kernel_vs_naive_vmap"][1]
    # time for the whole population (measured for the kernel, from the throughput for the others)
    rec["time_full_P_s"] = {"kernel": rec["kernel"]["median_s"], "naive_vmap": dist / nv, "numpy": dist / nu}
    rec["done"] = True
    return rec


def config_line(rec: dict) -> str:
    k, nv, nu = rec["kernel"], rec["naive_vmap"], rec["numpy"]
    star = lambda r: f" on P={r['P_measured']}*" if r["subset"] else ""  # noqa: E731
    flag = "" if rec["agree"] else f"  !! DISAGREE > {TOLERANCE:g}"
    g = rec.get("kernel_grad")
    if g:
        flag += (f"\n        kernel gradient {fmt_rate(g['evals_per_s'])}/s on P={g['P_measured']} "
                 f"({g['median_s'] * 1e3:.3g} ms; {g['slowdown_vs_forward']:.3g}x slower per distance than the "
                 f"forward kernel; compile {g['compile_s']:.2f} s)")
    return (f"kernel {fmt_rate(k['evals_per_s'])}/s ({k['median_s'] * 1e3:.3g} ms, cpu/wall "
            f"{fmt(k.get('cpu_per_wall'), '.2f')}, compile {k['compile_s']:.2f} s) | "
            f"naive {fmt_rate(nv['evals_per_s'])}/s{star(nv)} | numpy {fmt_rate(nu['evals_per_s'])}/s{star(nu)} | "
            f"x{rec['kernel_vs_numpy']:.3g} numpy, x{rec['kernel_vs_naive_vmap']:.3g} naive{round_ranges(rec)} | "
            f"max_rel_diff {rec['max_rel_diff']:.2g}{flag}")


def round_ranges(rec: dict) -> str:
    """`` (over 3 rounds: numpy 41-47x, naive 8.1-9x)``: the spread of the ratios over the
    side-by-side rounds (empty for results written before rounds were recorded)."""
    rr = rec.get("ratio_range")
    return _ranges_text(rec.get("rounds"), rr["kernel_vs_numpy"], rr["kernel_vs_naive_vmap"]) if rr else ""


def ratio_ranges(h: dict) -> str:
    """:func:`round_ranges` for a headline."""
    if not h.get("kernel_vs_numpy_range"):
        return ""
    return _ranges_text(h["ratio_rounds"], h["kernel_vs_numpy_range"], h["kernel_vs_naive_vmap_range"])


def _ranges_text(rounds, numpy_range, naive_range) -> str:
    return (f" (over {rounds} rounds: numpy {numpy_range[0]:.3g}-{numpy_range[2]:.3g}x, "
            f"naive {naive_range[0]:.3g}-{naive_range[2]:.3g}x)")


def config_key(L, N, P) -> str:
    return f"L{L}_N{N}_P{P}"
