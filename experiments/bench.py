"""Benchmark harness: objective throughput, end-to-end fit speed, peak memory (``make bench``).

Objective throughput is counted in point-to-capsule distance evaluations per
second: a call that scores ``P`` individuals of ``L`` capsules against ``N`` cloud
points evaluates ``P * N * L`` distances (``N`` is the cloud's array size,
padding included, as in ``FitResult.distance_evaluations``).  Three
implementations of the same data term are timed on the same inputs:

- ``kernel``: :func:`jaxpose.objective.data_cost`, jit-compiled (the streaming kernel);
- ``naive_vmap``: ``jax.jit(jax.vmap(per_individual_cost))`` where the per-individual
  cost forms the ``(N, L)`` distance matrix with
  :func:`jaxpose.objective.point_capsule_distance` (so ``(P, N, L)`` under vmap);
- ``numpy``: a loop over individuals, each vectorised over points and links with
  NumPy on ``(N, L)`` coordinate arrays (single core).

Each is compiled / warmed up first (compile time reported separately), then the
three are timed side by side, in rounds that call each in turn (so that the
machine's drift falls on all three alike); a throughput is the median of its calls
ended by ``block_until_ready``, a ratio the median of the rounds' ratios, with their
spread over the rounds beside it.  NumPy and the naive
version run on the first ``P'`` individuals when the whole population would take
too long (NumPy: ``--numpy-seconds``) or too much memory (naive: ``--naive-max-mb``);
their throughput is linear in ``P`` and is reported as measured, marked ``*``.

End to end: fits of rendered spider / humanoid images with the public search
(``jaxpose.search``), compile time apart from run time, objective evaluations per
second, and link accuracy (symmetric PCP) after every epoch, so that the time to
reach an accuracy can be read.

Peak memory: each probe runs in a fresh subprocess; see ``docs/performance.md``.

Usage::

    python experiments/bench.py                 # full grid (make bench)
    python experiments/bench.py --grid small    # a few minutes
    python experiments/bench.py --quick --json quick.json   # about a minute
    python experiments/bench.py --resume        # continue an interrupted run

Outputs (``--out-dir``, default ``experiments/results``): ``bench.json`` (rewritten
atomically after every configuration), ``bench.md`` and ``bench_scaling.png``;
``--quick`` writes ``bench_quick.json`` / ``bench_quick.md`` instead.
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import platform
import resource
import statistics
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
if REPO not in sys.path:  # run as a script from anywhere without installing
    sys.path.insert(0, REPO)
if HERE not in sys.path:  # experiments/common.py
    sys.path.insert(0, HERE)

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402

from common import cpu_model  # noqa: E402  (experiments/common.py)
from jaxpose.io.atomic import atomic_write  # noqa: E402
from jaxpose.objective import Cloud, ObjectiveConfig, cloud_spread, data_cost, point_capsule_distance  # noqa: E402

SCHEMA = 1
EPS = 1e-12
TOLERANCE = 1e-5  # the three costs must agree to this relative difference

# links -> skeleton: the shipped spider (8) and humanoid (17), and a generated 40-link chain
# (the shipped snake has only 10 links)
SKELETONS = {8: "spider", 17: "humanoid", 40: "chain40"}
GRIDS = {
    "full": dict(P=(64, 256, 1024, 4096), N=(512, 2048, 8192, 32768), L=(8, 17, 40)),
    "small": dict(P=(64, 1024), N=(512, 2048, 8192), L=(8, 17, 40)),
    "quick": dict(P=(1024,), N=(2048,), L=(17,)),
}
REFERENCE = dict(P=1024, N=2048, L=17)  # the headline configuration
BACKEND_COMPILE_EVENT = "/jax/core/compile/backend_compile_duration"
COMPILE_EVENTS = (
    "/jax/core/compile/jaxpr_trace_duration",
    "/jax/core/compile/jaxpr_to_mlir_module_duration",
    BACKEND_COMPILE_EVENT,
)


# --------------------------------------------------------------------------- small helpers


def log(msg: str = "") -> None:
    print(msg, flush=True)


def now_iso() -> str:
    return datetime.datetime.now(datetime.timezone.utc).replace(microsecond=0).isoformat()


def clean(x):
    """JSON-ready: NumPy scalars/arrays to Python, non-finite floats to None."""
    if isinstance(x, dict):
        return {str(k): clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [clean(v) for v in x]
    if isinstance(x, (np.ndarray, jax.Array)):
        return clean(np.asarray(x).tolist())
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        x = float(x)
        return x if math.isfinite(x) else None
    return x


def atomic_write_text(path: str, text: str) -> None:
    """Write ``text`` to a temporary file beside ``path`` and rename it over ``path``."""
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    atomic_write(path, lambda f: f.write(text))


def write_json(path: str, data) -> None:
    atomic_write_text(path, json.dumps(clean(data), indent=2, allow_nan=False) + "\n")


def fmt_rate(x) -> str:
    if x is None:
        return "-"
    for unit, scale in (("G", 1e9), ("M", 1e6), ("k", 1e3)):
        if x >= scale:
            return f"{x / scale:.3g}{unit}"
    return f"{x:.3g}"


def fmt(x, spec: str = ".3g", none: str = "-") -> str:
    return none if x is None else format(x, spec)


class CompileWatch:
    """Collects jax's compile events (trace, lowering, XLA backend compile) while active."""

    def __init__(self):
        self.events: list[tuple[str, float, str]] = []

    def _listener(self, event, duration, **kwargs):
        if event in COMPILE_EVENTS:
            self.events.append((event, float(duration), str(kwargs.get("fun_name", "?"))))

    def __enter__(self):
        jax.monitoring.register_event_duration_secs_listener(self._listener)
        return self

    def __exit__(self, *exc):
        jax.monitoring.unregister_event_duration_listener(self._listener)
        return False

    @property
    def seconds(self) -> float:
        return sum(d for _, d, _ in self.events)

    @property
    def compiles(self) -> list[str]:
        return [n for e, _, n in self.events if e == BACKEND_COMPILE_EVENT]


# --------------------------------------------------------------------------- machine


def memory_gib():
    try:
        return round(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30, 1)
    except (ValueError, OSError, AttributeError):
        return None


def git_commit():
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True, text=True,
                              timeout=10).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no", "jaxpose"], cwd=REPO,
                               capture_output=True, text=True, timeout=10).stdout.strip()
        return (head + ("+dirty" if dirty else "")) or None
    except (OSError, subprocess.SubprocessError):
        return None


def package_version(name: str):
    try:
        from importlib.metadata import version

        return version(name)
    except Exception:  # noqa: BLE001 - metadata is best effort
        return None


def machine_info() -> dict:
    try:
        usable = len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        usable = os.cpu_count()
    try:
        load = [round(x, 2) for x in os.getloadavg()]
    except OSError:
        load = None
    return {
        "cpu": cpu_model(),
        "cores": os.cpu_count(),
        "cores_usable": usable,
        "memory_gib": memory_gib(),
        "platform": platform.platform(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "jax": jax.__version__,
        "jaxlib": package_version("jaxlib"),
        "backend": jax.default_backend(),
        "devices": [f"{d.platform}:{d.device_kind}" for d in jax.devices()],
        "xla_flags": os.environ.get("XLA_FLAGS"),
        "git": git_commit(),
        "load_average_start": load,
    }


def machine_line(m: dict) -> str:
    return (f"{m['cpu']}, {m['cores_usable']} usable of {m['cores']} logical cores, {m['memory_gib']} GiB; "
            f"jax {m['jax']} (jaxlib {m['jaxlib']}), backend {m['backend']} ({', '.join(m['devices'])}); "
            f"numpy {m['numpy']}; Python {m['python']}")


def load_note(m: dict):
    """A warning when the machine was busy while measuring (load average above half the cores)."""
    loads = [x for x in (m.get("load_average_start"), m.get("load_average_end")) if x]
    if not loads:
        return None
    worst = max(x[0] for x in loads)
    if worst > 0.5 * (m.get("cores_usable") or 1):
        return (f"the machine was busy (1-minute load average up to {worst:.1f} on {m.get('cores_usable')} cores): "
                "timings are noisy and low; compare ratios rather than absolute numbers")
    return None


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
    from jaxpose.kinematics import forward_kinematics
    from jaxpose.genome import decode

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


def compile_timed(jitted, args):
    """``(compiled, seconds, xla_temp_bytes)``: trace + lower + XLA compile, timed."""
    t = time.perf_counter()
    compiled = jitted.lower(*args).compile()
    dt = time.perf_counter() - t
    temp = None
    try:
        ma = compiled.memory_analysis()
        temp = int(ma.temp_size_in_bytes) if ma is not None else None
    except Exception:  # noqa: BLE001 - not every backend reports it
        pass
    return compiled, dt, temp


def time_calls(fn, min_repeats: int, max_repeats: int, budget_s: float):
    """Call ``fn`` (already warm) until ``min_repeats`` calls and ``budget_s`` seconds are
    both reached, or ``max_repeats`` calls; returns ``(times, last output)``."""
    times, cpu, out = [], [], None
    while len(times) < max_repeats:
        c = time.process_time()
        t = time.perf_counter()
        out = jax.block_until_ready(fn())
        times.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c)
        if len(times) >= min_repeats and sum(times) >= budget_s:
            break
    return Timings(times, cpu), out


def time_interleaved(fns: dict, min_rounds: int, max_rounds: int, budget_s: float):
    """Time several implementations side by side: in rounds, each called in turn, so that
    the machine's drift (other load, clock changes) falls on all of them alike.

    In each round every implementation runs for about as long as the slowest one's
    single call (fast ones are called several times, at most ``max_rounds // min_rounds``).
    Rounds go on until ``min_rounds`` of them and ``budget_s`` seconds are both reached,
    or ``max_rounds``.  Returns ``({name: Timings of all calls}, {name: last output},
    [{name: median seconds of the round}, ...])``.
    """
    first = {}
    for name, fn in fns.items():  # one call each to size the rounds (all are warm)
        t = time.perf_counter()
        jax.block_until_ready(fn())
        first[name] = time.perf_counter() - t
    slowest = max(first.values())
    cap = max(1, max_rounds // max(min_rounds, 1))
    reps = {name: int(min(cap, max(1, round(slowest / max(s, 1e-9))))) for name, s in first.items()}
    wall = {name: [] for name in fns}
    cpu = {name: [] for name in fns}
    outs, rounds = {}, []
    start = time.perf_counter()
    while len(rounds) < max_rounds:
        this = {}
        for name, fn in fns.items():
            ts = []
            for _ in range(reps[name]):
                c = time.process_time()
                t = time.perf_counter()
                outs[name] = jax.block_until_ready(fn())
                ts.append(time.perf_counter() - t)
                cpu[name].append(time.process_time() - c)
            wall[name] += ts
            this[name] = statistics.median(ts)
        rounds.append(this)
        if len(rounds) >= min_rounds and time.perf_counter() - start >= budget_s:
            break
    return {name: Timings(wall[name], cpu[name]) for name in fns}, outs, rounds


def round_ratios(rounds: list[dict], counts: dict, a: str, b: str) -> list[float]:
    """``[lowest, median, highest]`` over the rounds of ``a``'s throughput over ``b``'s, each
    round's from its own median call times (``rounds`` as :func:`time_interleaved` returns
    them; ``counts``: distances per call)."""
    r = sorted((counts[a] / x[a]) / (counts[b] / x[b]) for x in rounds)
    return [r[0], statistics.median(r), r[-1]]


class Timings(list):
    """Wall-clock seconds of the calls, with the process CPU seconds (all threads) in ``.cpu``."""

    def __init__(self, wall, cpu):
        super().__init__(wall)
        self.cpu = cpu


def timing_record(times, distances: int) -> dict:
    """Median wall time and throughput; also the CPU time: ``cpu_per_wall`` above 1 means several
    threads worked, below 1 that the process waited (for a busy machine's cores), and
    ``evals_per_cpu_s`` is the throughput per CPU-second, less sensitive to other load."""
    med = statistics.median(times)
    rec = {"median_s": med, "min_s": min(times), "max_s": max(times), "repeats": len(times),
           "evals_per_s": distances / med}
    cpu = getattr(times, "cpu", None)
    if cpu:
        cmed = statistics.median(cpu)
        rec.update(cpu_median_s=cmed, cpu_per_wall=sum(cpu) / max(sum(times), 1e-12),
                   evals_per_cpu_s=distances / cmed if cmed > 0 else None)
    return rec


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


# --------------------------------------------------------------------------- end to end


E2E_PRESETS = {
    # the shipped defaults (FitConfig(): islands, memetic and final refinement)
    "default": dict(),
    # small and without gradient refinement: compiles in a fraction of the time
    "quick": dict(population=128, generations=40, chunk=10, memetic_every=0, final_refine_steps=0),
}


def _fit_module():
    import importlib

    return importlib.import_module("jaxpose.search.fit")  # the module (``jaxpose.search.fit`` is also a function)


def fit_traced(skel, config, cloud, key):
    """One fit, as :class:`jaxpose.search.Fitter` runs it (init, epochs, finish), recording the
    elapsed time, evaluations and best genome after every epoch.  Falls back to ``Fitter.run``
    with a progress callback (no per-epoch genomes) if the compiled pieces are not found."""
    F = _fit_module()
    cloud = Cloud(jnp.asarray(cloud.points, jnp.float32), jnp.asarray(cloud.weights, jnp.float32))
    snaps = []
    if all(hasattr(F, n) for n in ("_programs", "_epochs")):
        t0 = time.perf_counter()
        pieces = F._programs(cloud, skel, key, config)  # Fitter's compiled pieces (compiled now when cold)
        st = pieces.init(cloud, skel, key)
        E, n_full, rem = F._epochs(config)
        hists, gen = [], 0
        for length in [E] * n_full + ([rem] if rem else []):
            st, h = pieces.epoch(skel, config, st, length)
            hists.append(h)
            gen += length
            best = float(h[-1])  # synchronises, as Fitter's progress report does
            snaps.append(dict(generation=gen, elapsed_s=time.perf_counter() - t0, best_cost=best,
                              evaluations=(st.objective_evaluations, st.gradient_evaluations),
                              genome=st.algo_state.best_solution, fitness=st.algo_state.best_fitness,
                              bounds=st.bounds))
        res = jax.block_until_ready(pieces.finish(cloud, skel, config, st, jnp.concatenate(hists)))
        wall = time.perf_counter() - t0
    else:
        from jaxpose.search import Fitter

        t0 = time.perf_counter()

        def progress(gen, best, evals):
            snaps.append(dict(generation=gen, elapsed_s=time.perf_counter() - t0, best_cost=best,
                              evaluations=(evals, 0), genome=None, fitness=None, bounds=None))

        res = Fitter(skel, config).run(cloud, key, progress)
        wall = time.perf_counter() - t0
    for s in snaps:
        s["evaluations"] = int(sum(int(np.sum(np.asarray(x))) for x in s["evaluations"]))
        if s["genome"] is not None and np.ndim(s["genome"]) == 2:  # islands: the best island's best
            i = int(np.argmin(np.asarray(s["fitness"])))
            s["genome"] = s["genome"][i]  # the bounds are shared by all islands
    return res, wall, snaps


def _links_of(skel):
    from jaxpose.kinematics import forward_kinematics
    from jaxpose.genome import decode

    @jax.jit
    def links(bounds, genome):
        lk = forward_kinematics(skel, decode(skel, bounds, genome))
        return lk.start, lk.end

    return links


def run_e2e(name: str, args) -> dict:
    from jaxpose import render as R
    from jaxpose.camera import depth_to_cloud
    from jaxpose.metrics import evaluate
    from jaxpose.search import FitConfig

    skel = get_skeleton(name)
    config = FitConfig(**E2E_PRESETS[args.e2e_preset]).for_skeleton(skel)  # generations resolved
    t = time.perf_counter()
    views, clouds = [], []
    for i in range(args.e2e_images):
        pose = R.random_pose(skel, np.random.default_rng([args.seed, i]))
        view = R.render_orbit(skel, pose, elevation_deg=20.0, azimuth_deg=40.0 * i, seed=args.seed + i)
        views.append(view)
        clouds.append(depth_to_cloud(view.depth, view.intrinsics, max_points=args.e2e_points, seed=i))
    render_s = time.perf_counter() - t
    links_of = _links_of(skel)

    def accuracy(view, start, end) -> dict:
        ev = evaluate(np.asarray(start), np.asarray(end), view.start, view.end, skel)
        return {"pcp_symmetric": ev["symmetric"]["pcp"], "pcp_strict": ev["strict"]["pcp"],
                "mpjpe_mm_symmetric": ev["symmetric"]["mpjpe_mm"]}

    runs = []
    for i, (view, cloud) in enumerate(zip(views, clouds)):
        with CompileWatch() as cw:
            res, wall, snaps = fit_traced(skel, config, cloud, jax.random.key(args.seed + i))
        evals = int(res.objective_evaluations) + int(res.gradient_evaluations)
        traj = []
        for s in snaps:
            acc = accuracy(view, *links_of(s["bounds"], s["genome"])) if s["genome"] is not None else {}
            traj.append({k: s[k] for k in ("generation", "elapsed_s", "evaluations", "best_cost")} | acc)
        final = accuracy(view, res.links.start, res.links.end)
        traj.append({"generation": config.generations, "elapsed_s": wall, "evaluations": evals,
                     "best_cost": float(res.cost), "final": True} | final)
        runs.append({
            "image": i, "cold": i == 0, "wall_s": wall, "compile_s": cw.seconds, "compiles": len(cw.compiles),
            "compiled": sorted(set(cw.compiles)), "objective_evaluations": int(res.objective_evaluations),
            "gradient_evaluations": int(res.gradient_evaluations),
            "distance_evaluations": float(res.distance_evaluations), "cost": float(res.cost),
            "points_used": int(np.sum(np.asarray(cloud.weights) > 0)), **final, "trajectory": traj,
        })
        log(f"    {name} image {i} ({'cold' if i == 0 else 'warm'}): {wall:.2f} s "
            f"(compile {cw.seconds:.1f} s, {len(cw.compiles)} executables), {evals} evaluations, "
            f"cost {float(res.cost):.4f}, symmetric PCP {final['pcp_symmetric']:.3f}")
    warm = [r for r in runs if not r["cold"]] or runs
    run_s = statistics.median(r["wall_s"] - (r["compile_s"] if r["cold"] else 0.0) for r in warm)
    evals = statistics.median(r["objective_evaluations"] + r["gradient_evaluations"] for r in warm)
    dists = statistics.median(r["distance_evaluations"] for r in warm)
    thresholds = {}
    for thr in args.e2e_pcp:
        reached = []
        for r in warm:  # the first snapshot from which the accuracy stays at or above thr to the end
            hit = None
            for p in r["trajectory"][::-1]:
                if p.get("pcp_symmetric", -1) < thr - 1e-9:
                    break
                hit = p["elapsed_s"]
            reached.append(hit)
        got = [x for x in reached if x is not None]
        thresholds[f"{thr:g}"] = {"reached": len(got), "of": len(reached),
                                  "median_s": statistics.median(got) if got else None}
    return {
        "skeleton": name, "L": skel.num_links, "max_points": args.e2e_points, "preset": args.e2e_preset,
        "config": {k: v for k, v in config.to_dict().items() if k != "objective"},
        "render_s": render_s,
        "compile_s": runs[0]["compile_s"],  # trace + lowering + XLA, summed over the compiling threads
        # what a user waits: the cold fit minus a warm one (unknown without a warm fit)
        "compile_wall_s": runs[0]["wall_s"] - run_s if len(runs) > 1 else None,
        "cold_wall_s": runs[0]["wall_s"],
        "warm_run_s": run_s,
        "evaluations": evals,
        "evals_per_s": evals / run_s,
        "distance_evals_per_s": dists / run_s,
        "recompiles_warm": sum(r["compiles"] for r in runs if not r["cold"]),
        "pcp_symmetric_mean": float(np.mean([r["pcp_symmetric"] for r in runs])),
        "pcp_symmetric": [r["pcp_symmetric"] for r in runs],
        "time_to_pcp": thresholds,
        "runs": runs,
        "done": True,
    }


# --------------------------------------------------------------------------- peak memory


def _status_kib(field: str):
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith(field + ":"):
                    return int(line.split()[1])
    except OSError:
        pass
    return None


def _peak_kib() -> int:
    hwm = _status_kib("VmHWM")
    return hwm if hwm is not None else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss


def _reset_peak() -> bool:
    """Reset the kernel's peak-RSS mark to the current RSS (Linux >= 4.0); False if not allowed."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def probe_main(spec: dict) -> dict:
    """In a fresh process: build the problem, then compile and run one method once, reading
    the peak resident set size (VmHWM, else ru_maxrss) before, after compiling and after running."""
    L, N, P, method = spec["L"], spec["N"], spec["P"], spec["method"]
    Pm = spec.get("P_run", P)
    pr = make_problem(L, N, P, spec["seed"])
    jax.block_until_ready(jnp.zeros(1) + 1)
    out = {"method": method, "L": L, "N": N, "P": P, "P_run": Pm, "rss_baseline_mib": _status_kib("VmRSS") / 1024,
           "peak_baseline_mib": _peak_kib() / 1024}
    if method == "numpy":
        reset = _reset_peak()
        base = _peak_kib()
        numpy_cost(pr["points"], pr["weights"], pr["sigma"], pr["start"][:Pm], pr["end"][:Pm], pr["radius"][:Pm])
        out.update(peak_reset=reset, compile_peak_mib=None, run_peak_over_baseline_mib=(_peak_kib() - base) / 1024)
        return out
    jitted, args = ((kernel_fn(spec["block"]), kernel_args(pr, Pm)) if method == "kernel"
                    else (naive_cost, naive_args(pr, Pm)))
    base = _peak_kib()
    compiled, c_s, temp = compile_timed(jitted, args)
    after_compile = _peak_kib()
    reset = _reset_peak()
    base_run = _peak_kib() if reset else base
    jax.block_until_ready(compiled(*args))
    after_run = _peak_kib()
    out.update(compile_s=c_s, xla_temp_bytes=temp, peak_reset=reset,
               compile_peak_over_baseline_mib=(after_compile - base) / 1024,
               run_peak_over_baseline_mib=(after_run - base_run) / 1024,
               peak_total_mib=max(after_compile, after_run) / 1024)
    return out


def run_probe(spec: dict, timeout: float = 600.0) -> dict:
    cmd = [sys.executable, os.path.abspath(__file__), "--probe", json.dumps(spec)]
    try:
        p = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return {**spec, "error": f"timed out after {timeout:.0f} s"}
    for line in p.stdout.splitlines()[::-1]:
        if line.startswith("PROBE_RESULT "):
            return {**spec, **json.loads(line[len("PROBE_RESULT "):])}
    return {**spec, "error": (p.stderr.strip().splitlines() or ["no output"])[-1][:300]}


def memory_probes(results: dict, args) -> list[dict]:
    """Probes for the reference configuration and the largest one measured."""
    done = [r for r in results["configs"].values() if r.get("done")]
    if not done:
        return []
    targets = []
    ref = results["configs"].get(config_key(REFERENCE["L"], REFERENCE["N"], REFERENCE["P"]))
    if ref:
        targets.append(ref)
    big = max(done, key=lambda r: r["distances"])
    if big is not ref:
        targets.append(big)
    specs = []
    for r in targets:
        for method, Pm in (("kernel", r["P"]), ("naive_vmap", r["naive_vmap"]["P_measured"]), ("numpy", 1)):
            specs.append({"method": method, "L": r["L"], "N": r["N"], "P": r["P"], "P_run": Pm, "seed": args.seed,
                          "block": args.block})
    return specs


def probe_key(spec) -> str:
    return f"{spec['method']}_L{spec['L']}_N{spec['N']}_P{spec['P']}_run{spec['P_run']}"


# --------------------------------------------------------------------------- report


def headline(results: dict) -> dict:
    r = results["configs"].get(config_key(REFERENCE["L"], REFERENCE["N"], REFERENCE["P"]))
    if not r or not r.get("done"):
        return {}
    return {
        "reference_config": dict(REFERENCE, skeleton=r["skeleton"]),
        "kernel_evals_per_s": r["kernel"]["evals_per_s"],
        "naive_vmap_evals_per_s": r["naive_vmap"]["evals_per_s"],
        "numpy_evals_per_s": r["numpy"]["evals_per_s"],
        "kernel_vs_numpy": r["kernel_vs_numpy"],
        "kernel_vs_naive_vmap": r["kernel_vs_naive_vmap"],
        "ratio_rounds": r.get("rounds"),
        "kernel_vs_numpy_range": (r.get("ratio_range") or {}).get("kernel_vs_numpy"),
        "kernel_vs_naive_vmap_range": (r.get("ratio_range") or {}).get("kernel_vs_naive_vmap"),
        "max_rel_diff": r["max_rel_diff"],
        "kernel_compile_s": r["kernel"]["compile_s"],
        "kernel_cpu_per_wall": r["kernel"].get("cpu_per_wall"),
        "kernel_evals_per_cpu_s": r["kernel"].get("evals_per_cpu_s"),
        "kernel_grad_evals_per_s": (r.get("kernel_grad") or {}).get("evals_per_s"),
        "kernel_grad_slowdown_vs_forward": (r.get("kernel_grad") or {}).get("slowdown_vs_forward"),
        "kernel_grad_P_measured": (r.get("kernel_grad") or {}).get("P_measured"),
        "kernel_grad_compile_s": (r.get("kernel_grad") or {}).get("compile_s"),
        "naive_vmap_compile_s": r["naive_vmap"]["compile_s"],
        "naive_vmap_P_measured": r["naive_vmap"]["P_measured"],
        "numpy_P_measured": r["numpy"]["P_measured"],
    }


def markdown(results: dict) -> str:
    m = results["machine"]
    out = [f"# jaxpose benchmark ({results['mode']})", ""]
    out.append(f"- Machine: {machine_line(m)}")
    out.append(f"- Platform: {m['platform']}; XLA_FLAGS: {m.get('xla_flags') or '(none)'}")
    out.append(f"- Load average (1, 5, 15 min) at start: {m.get('load_average_start')}, "
               f"at end: {m.get('load_average_end')}")
    out.append(f"- Code: git {m.get('git')}; started {results['started']}, updated {results['updated']}"
               + (f" (resumed at {', '.join(m['resumed_at'])})" if m.get("resumed_at") else ""))
    note = load_note(m)
    if note:
        out += ["", f"> **Note:** {note}."]
    s = results["settings"]
    out += ["", "## Objective throughput", "",
            "Point-to-capsule distance evaluations per second (P·N·L / median time of a call), "
            f"kernel block {s['block']}; `*`: measured on the first P′ individuals (shown) of the population. "
            "kernel CPU/wall: process CPU time over wall time during the timed calls (above 1: several threads; "
            "below 1: the process waited for a core, i.e. the machine was busy); kernel dist/CPU-s: distances per "
            "CPU-second, less sensitive to other load. "
            "The three are timed side by side in rounds; ratios are medians over the rounds of each round's ratio "
            "of throughputs (so not always the quotient of the columns). max rel diff: largest relative difference "
            "between any two of the three "
            f"costs (must be ≤ {TOLERANCE:g}).", "",
            "| skeleton (L) | N | P | P·N·L | kernel compile s | kernel ms | kernel dist/s | kernel CPU/wall "
            "| kernel dist/CPU-s "
            "| naive vmap dist/s | NumPy dist/s | kernel/NumPy | kernel/naive | max rel diff | kernel XLA temp MiB "
            "| naive XLA temp MiB (full P) |",
            "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    recs = sorted((r for r in results["configs"].values() if r.get("done")), key=lambda r: (r["L"], r["N"], r["P"]))
    mib = lambda b: "-" if b is None else f"{b / 2**20:.3g}"  # noqa: E731

    def sub(r):
        return f"{fmt_rate(r['evals_per_s'])}" + (f" (P′={r['P_measured']})*" if r["subset"] else "")

    for r in recs:
        k = r["kernel"]
        out.append(
            f"| {r['skeleton']} ({r['L']}) | {r['N']} | {r['P']} | {r['distances']:.3g} | {k['compile_s']:.2f} "
            f"| {k['median_s'] * 1e3:.3g} | {fmt_rate(k['evals_per_s'])} | {fmt(k.get('cpu_per_wall'), '.2f')} "
            f"| {fmt_rate(k.get('evals_per_cpu_s'))} "
            f"| {sub(r['naive_vmap'])} "
            f"| {sub(r['numpy'])} | {r['kernel_vs_numpy']:.3g} | {r['kernel_vs_naive_vmap']:.3g} "
            f"| {r['max_rel_diff']:.2g}{'' if r['agree'] else ' ✗'} | {mib(k['xla_temp_bytes'])} "
            f"| {mib(r['naive_vmap']['xla_temp_bytes_full_P'])} |")
    grads = [r for r in recs if r.get("kernel_grad")]
    if grads:
        out += ["", "Kernel gradient (`jax.grad` of the summed cost with respect to the capsule ends, as used by "
                "the memetic and final refinement) on the first P′ individuals, distances per second counting one "
                "forward+backward pass as P′·N·L; slowdown: forward kernel throughput (full P) / gradient "
                "throughput.", "",
                "| skeleton (L) | N | P′ | compile s | ms | dist/s | slowdown |",
                "|---|---:|---:|---:|---:|---:|---:|"]
        for r in grads:
            g = r["kernel_grad"]
            out.append(f"| {r['skeleton']} ({r['L']}) | {r['N']} | {g['P_measured']} | {g['compile_s']:.2f} "
                       f"| {g['median_s'] * 1e3:.3g} | {fmt_rate(g['evals_per_s'])} "
                       f"| {g['slowdown_vs_forward']:.3g} |")
    blocks = [r for r in recs if r.get("kernel_blocks")]
    if blocks:
        sizes = sorted({int(b) for r in blocks for b in r["kernel_blocks"]} | {s["block"]})
        out += ["", "Kernel throughput by block size (dist/s):", "",
                "| skeleton (L) | N | P | " + " | ".join(f"block {b}" for b in sizes) + " |",
                "|---|---:|---:|" + "---:|" * len(sizes)]
        for r in blocks:
            cells = []
            for b in sizes:
                x = r["kernel"] if b == s["block"] else r["kernel_blocks"].get(str(b))
                cells.append(fmt_rate(x["evals_per_s"]) if x else "-")
            out.append(f"| {r['skeleton']} ({r['L']}) | {r['N']} | {r['P']} | " + " | ".join(cells) + " |")
    h = results.get("headline") or {}
    if h:
        out += ["", f"Reference configuration (P={REFERENCE['P']}, N={REFERENCE['N']}, L={REFERENCE['L']}): "
                f"kernel {fmt_rate(h['kernel_evals_per_s'])}/s, naive vmap {fmt_rate(h['naive_vmap_evals_per_s'])}/s, "
                f"NumPy {fmt_rate(h['numpy_evals_per_s'])}/s; kernel/NumPy {h['kernel_vs_numpy']:.3g}, "
                f"kernel/naive {h['kernel_vs_naive_vmap']:.3g}{ratio_ranges(h)}; max rel diff {h['max_rel_diff']:.2g}."]
    e2e = [e for e in (results.get("e2e") or {}).values() if e.get("done")]
    if e2e:
        thr = sorted({t for e in e2e for t in e["time_to_pcp"]}, key=float)
        out += ["", "## End-to-end fit", "",
                "Rendered images (Kinect v1 sensor model), `depth_to_cloud` with `max_points`; one cold fit "
                "(compiles) then warm fits of other images of the same padded size. evals: objective + gradient "
                "evaluations of a warm fit; PCP: symmetric, mean over all images; t(PCP ≥ x): elapsed time of a "
                "warm fit from which on the best-so-far pose's symmetric PCP stays ≥ x (checked after every "
                "epoch and at the end), median over the warm fits that got there (got there/fits). compile s: "
                "the cold fit's wall time minus the warm fit's (what a user waits); compile work s: jax's "
                "trace, lowering and XLA compile events summed, larger since the pieces compile in two "
                "threads while Python traces the next.", "",
                "| skeleton (L) | max points | population × generations | compile s | compile work s | warm fit s "
                "| evals | evals/s | dist/s | recompiles (warm) | PCP | "
                + " | ".join(f"t(PCP≥{t}) s" for t in thr) + " |",
                "|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|" + "---:|" * len(thr)]
        for e in e2e:
            c = e["config"]
            cells = []
            for t in thr:
                x = e["time_to_pcp"].get(t)
                cells.append("-" if not x else f"{fmt(x['median_s'], '.3g')} ({x['reached']}/{x['of']})")
            out.append(
                f"| {e['skeleton']} ({e['L']}) | {e['max_points']} | {c['population']} × {c['generations']} "
                f"({e['preset']}) | {fmt(e.get('compile_wall_s'), '.1f')} | {e['compile_s']:.1f} "
                f"| {e['warm_run_s']:.2f} | {e['evaluations']:.0f} "
                f"| {fmt_rate(e['evals_per_s'])} | {fmt_rate(e['distance_evals_per_s'])} | {e['recompiles_warm']} "
                f"| {e['pcp_symmetric_mean']:.3f} | " + " | ".join(cells) + " |")
    mem = [p for p in (results.get("memory") or {}).values()]
    if mem:
        out += ["", "## Peak memory", "",
                "Each probe is a fresh process that builds the inputs, then compiles and runs one call. "
                "XLA temp: the executable's scratch buffers (`compiled.memory_analysis()`). Peak RSS over "
                "baseline: growth of the process's peak resident set (VmHWM) during compilation and during the "
                "call (peak mark reset in between where Linux allows).", "",
                "| method | skeleton (L) | N | P run | XLA temp MiB | baseline RSS MiB | compile peak +MiB "
                "| run peak +MiB |", "|---|---|---:|---:|---:|---:|---:|---:|"]
        for p in sorted(mem, key=lambda p: (p["L"] * p["N"] * p["P"], p["method"])):
            if p.get("error"):
                out.append(f"| {p['method']} | L={p['L']} | {p['N']} | {p['P_run']} | error: {p['error']} | | | |")
                continue
            out.append(f"| {p['method']} | {SKELETONS.get(p['L'], '?')} ({p['L']}) | {p['N']} | {p['P_run']} "
                       f"| {mib(p.get('xla_temp_bytes'))} | {p['rss_baseline_mib']:.0f} "
                       f"| {fmt(p.get('compile_peak_over_baseline_mib'), '.0f')} "
                       f"| {fmt(p.get('run_peak_over_baseline_mib'), '.0f')} |")
    if results.get("plot"):
        out += ["", f"Scaling plot: `{os.path.basename(results['plot'])}`."]
    return "\n".join(out) + "\n"


# --------------------------------------------------------------------------- main


def parse_args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                 formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    ap.add_argument("--grid", choices=("full", "small"), default="full", help="configuration grid")
    ap.add_argument("--quick", action="store_true",
                    help="about a minute: only P=1024, N=2048, L=17, memory probes for it, no end-to-end fit")
    ap.add_argument("--json", metavar="FILE", help="JSON results file (default OUT_DIR/bench.json, "
                                                   "bench_quick.json with --quick); the Markdown table "
                                                   "goes beside it (.md)")
    ap.add_argument("--out-dir", default=os.path.join(HERE, "results"), help="folder for the outputs")
    ap.add_argument("--resume", action="store_true", help="skip configurations already in the JSON file")
    ap.add_argument("--repeats", type=int, default=30,
                    help="most rounds of the side-by-side timing (and most timed calls of the other measurements)")
    ap.add_argument("--min-repeats", type=int, default=3,
                    help="fewest rounds of the side-by-side timing (and fewest calls of the other measurements)")
    ap.add_argument("--time-budget", type=float, default=2.0,
                    help="seconds of timed calls for the kernel and for the naive vmap (the rounds go on until "
                         "2 x this + --numpy-seconds); also each other measurement's budget")
    ap.add_argument("--numpy-seconds", type=float, default=3.0,
                    help="NumPy's share of the rounds' budget; one NumPy call takes about this / --min-repeats "
                         "(decides how many individuals it runs)")
    ap.add_argument("--naive-max-mb", type=float, default=1100.0,
                    help="largest XLA scratch memory of the naive vmap; beyond, it runs on fewer individuals")
    ap.add_argument("--block", type=int, default=ObjectiveConfig().block, help="kernel block size (points)")
    ap.add_argument("--blocks", type=lambda s: [int(x) for x in s.split(",") if x], default=None,
                    help="also time the kernel at these block sizes, e.g. 256,1024,4096")
    ap.add_argument("--grad", action="store_true",
                    help="time the kernel's gradient at every configuration (default: the reference one only)")
    ap.add_argument("--grad-P", type=int, default=64, help="individuals in the gradient measurement")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--no-e2e", dest="e2e", action="store_false", default=None, help="skip the end-to-end fits")
    ap.add_argument("--e2e", dest="e2e", action="store_true", help="run the end-to-end fits (also with --quick)")
    ap.add_argument("--e2e-skeletons", nargs="+", default=None, help="default spider humanoid (--quick: spider)")
    ap.add_argument("--e2e-images", type=int, default=None, help="images per skeleton (1 cold + warm ones; "
                                                                  "default 4, --grid small / --quick: 2)")
    ap.add_argument("--e2e-points", type=int, default=1024, help="max_points of the clouds")
    ap.add_argument("--e2e-preset", choices=sorted(E2E_PRESETS), default=None,
                    help="fit settings: default = FitConfig() (default), quick = small, no gradient refinement "
                         "(--quick)")
    ap.add_argument("--e2e-pcp", type=lambda s: [float(x) for x in s.split(",")], default=[0.5, 0.75, 0.9, 1.0],
                    help="accuracy thresholds for the time-to-accuracy columns")
    ap.add_argument("--no-memory", dest="memory", action="store_false", help="skip the peak-memory probes")
    ap.add_argument("--no-plot", dest="plot", action="store_false", help="skip the scaling plot")
    ap.add_argument("--probe", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    args.mode = "quick" if args.quick else args.grid
    if args.quick:
        args.time_budget, args.numpy_seconds = 1.0, 2.0
    if args.e2e is None:
        args.e2e = not args.quick
    args.e2e_skeletons = args.e2e_skeletons or (["spider"] if args.quick else ["spider", "humanoid"])
    args.e2e_images = args.e2e_images or (2 if args.mode in ("quick", "small") else 4)
    args.e2e_preset = args.e2e_preset or ("quick" if args.quick else "default")
    stem = "bench_quick" if args.quick else "bench"
    args.json = args.json or os.path.join(args.out_dir, stem + ".json")
    args.md = os.path.splitext(args.json)[0] + ".md"
    args.png = os.path.join(args.out_dir, "bench_scaling.png")
    return args


def settings_of(args) -> dict:
    return {"block": args.block, "seed": args.seed, "numpy_dtype": "float32", "naive_max_mb": args.naive_max_mb,
            "numpy_seconds": args.numpy_seconds, "repeats": args.repeats, "min_repeats": args.min_repeats,
            "time_budget_s": args.time_budget, "blocks": args.blocks, "e2e_points": args.e2e_points,
            "e2e_preset": args.e2e_preset, "e2e_images": args.e2e_images}


def load_previous(args, machine) -> dict | None:
    if not (args.resume and os.path.exists(args.json)):
        if args.resume:
            log(f"--resume: {args.json} does not exist, starting afresh")
        return None
    with open(args.json) as f:
        prev = json.load(f)
    if prev.get("schema") != SCHEMA:
        log(f"--resume: {args.json} has another schema, starting afresh")
        return None
    if prev.get("settings", {}).get("block") != args.block or prev.get("settings", {}).get("seed") != args.seed:
        log("--resume: block size or seed differ from the stored run, starting afresh")
        return None
    if prev.get("machine", {}).get("cpu") != machine["cpu"]:
        log(f"--resume: WARNING the stored results were measured on {prev['machine'].get('cpu')!r}")
    n = sum(1 for r in prev.get("configs", {}).values() if r.get("done"))
    log(f"--resume: {n} configurations already measured in {args.json}")
    return prev


def main(argv=None) -> int:
    args = parse_args(argv)
    if args.probe:
        res = probe_main(json.loads(args.probe))
        print("PROBE_RESULT " + json.dumps(clean(res)), flush=True)
        return 0

    machine = machine_info()
    prev = load_previous(args, machine)
    if prev:  # keep how busy the machine was when the earlier part was measured
        machine["load_average_start"] = prev.get("machine", {}).get("load_average_start") or \
            machine["load_average_start"]
        machine["resumed_at"] = prev.get("machine", {}).get("resumed_at", []) + [now_iso()]
    results = prev or {"configs": {}, "e2e": {}, "memory": {}, "started": now_iso()}
    results.update(schema=SCHEMA, mode=args.mode, grid=GRIDS[args.mode], machine=machine,
                   settings=settings_of(args), complete=False)
    results.setdefault("e2e", {})
    results.setdefault("memory", {})

    def save():
        results["updated"] = now_iso()
        results["machine"]["load_average_end"] = [round(x, 2) for x in os.getloadavg()]
        results["machine"]["peak_rss_mib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        results["headline"] = headline(results)
        results.update(results["headline"])  # the headline numbers also at the top level
        write_json(args.json, results)
        atomic_write_text(args.md, markdown(results))

    log(f"jaxpose benchmark, mode {args.mode}: {machine_line(machine)}")
    log(f"load average {machine['load_average_start']}; results -> {args.json}")
    note = load_note(machine)
    if note:
        log(f"NOTE: {note}")
    g = GRIDS[args.mode]
    configs = [(L, N, P) for L in g["L"] for N in g["N"] for P in g["P"]]
    t_start = time.perf_counter()
    try:
        log(f"\n== objective throughput: {len(configs)} configurations (point-to-capsule distances/s) ==")
        for i, (L, N, P) in enumerate(configs, 1):
            key = config_key(L, N, P)
            head = f"[{i:2d}/{len(configs)}] L={L:2d} {SKELETONS[L]:8s} N={N:5d} P={P:4d}"
            if results["configs"].get(key, {}).get("done"):
                log(f"{head}: done before (--resume), skipped")
                continue
            t = time.perf_counter()
            rec = measure_config(L, N, P, args)
            rec["wall_s"] = time.perf_counter() - t
            rec["load_average"] = [round(x, 2) for x in os.getloadavg()]
            rec["measured"] = now_iso()
            results["configs"][key] = rec
            save()
            log(f"{head}: {config_line(rec)} [{rec['wall_s']:.0f} s]")

        if args.e2e:
            log(f"\n== end to end: {', '.join(args.e2e_skeletons)}, preset {args.e2e_preset}, "
                f"{args.e2e_images} images each ==")
            for name in args.e2e_skeletons:
                key = f"{name}_{args.e2e_preset}_{args.e2e_points}"
                if results["e2e"].get(key, {}).get("done"):
                    log(f"  {name}: done before (--resume), skipped")
                    continue
                e = run_e2e(name, args)
                results["e2e"][key] = e
                save()
                t2 = ", ".join(f"PCP>={k}: {fmt(v['median_s'], '.3g')} s ({v['reached']}/{v['of']})"
                               for k, v in e["time_to_pcp"].items())
                log(f"  {name}: compile {fmt(e['compile_wall_s'], '.1f')} s "
                    f"(work {e['compile_s']:.1f} s in all threads), "
                    f"warm fit {e['warm_run_s']:.2f} s, "
                    f"{fmt_rate(e['evals_per_s'])} evals/s ({fmt_rate(e['distance_evals_per_s'])} dist/s), "
                    f"recompiles {e['recompiles_warm']}, mean symmetric PCP {e['pcp_symmetric_mean']:.3f}; {t2}")
        else:
            log("\n(end-to-end fits skipped" + (": --quick; add --e2e to include them)" if args.quick else ")"))

        if args.memory:
            specs = memory_probes(results, args)
            log(f"\n== peak memory: {len(specs)} probes, each in a fresh process ==")
            for spec in specs:
                key = probe_key(spec)
                if key in results["memory"] and not results["memory"][key].get("error"):
                    log(f"  {key}: done before (--resume), skipped")
                    continue
                p = run_probe(spec)
                results["memory"][key] = p
                save()
                if p.get("error"):
                    log(f"  {key}: ERROR {p['error']}")
                else:
                    temp = p['xla_temp_bytes'] / 2**20 if p.get('xla_temp_bytes') else None
                    log(f"  {key}: XLA temp {fmt(temp)} MiB, "
                        f"baseline RSS {p['rss_baseline_mib']:.0f} MiB, compile peak "
                        f"+{fmt(p.get('compile_peak_over_baseline_mib'), '.0f')} MiB, run peak "
                        f"+{fmt(p.get('run_peak_over_baseline_mib'), '.0f')} MiB")
    except KeyboardInterrupt:
        save()
        log(f"\ninterrupted: the finished measurements are in {args.json}; rerun with --resume to continue")
        return 130

    if args.plot and not args.quick:
        try:
            import bench_plot
        except ImportError:  # run from elsewhere
            sys.path.insert(0, HERE)
            import bench_plot
        path = bench_plot.plot_scaling(results, args.png)
        if path:  # relative to the JSON's folder: no path of this machine in the results
            results["plot"] = os.path.relpath(os.path.abspath(path), os.path.dirname(os.path.abspath(args.json)))
    results["complete"] = True
    results["wall_s"] = time.perf_counter() - t_start
    save()
    h = results.get("headline") or {}
    log(f"\ndone in {results['wall_s']:.0f} s: {args.json}, {args.md}" + (f", {results['plot']}" if
                                                                          results.get("plot") else ""))
    if h:
        log(f"reference P=1024 N=2048 L=17: kernel {fmt_rate(h['kernel_evals_per_s'])}/s, naive vmap "
            f"{fmt_rate(h['naive_vmap_evals_per_s'])}/s, numpy {fmt_rate(h['numpy_evals_per_s'])}/s; "
            f"kernel/numpy {h['kernel_vs_numpy']:.3g}, kernel/naive {h['kernel_vs_naive_vmap']:.3g}{ratio_ranges(h)}, "
            f"max_rel_diff {h['max_rel_diff']:.2g}")
    bad = [k for k, r in results["configs"].items() if r.get("done") and not r["agree"]]
    if bad:
        log(f"WARNING: the three costs differ by more than {TOLERANCE:g} (relative) in {', '.join(bad)}")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
