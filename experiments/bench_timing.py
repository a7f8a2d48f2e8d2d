"""How the benchmark times things (``bench.py``): compile apart from run, calls until a
budget, several implementations side by side in rounds, jax's compile events.

A time is a call ended by ``block_until_ready``; every timed call also records the
process CPU time (all threads), so that a busy machine shows (:func:`timing_record`).
"""

from __future__ import annotations

import statistics
import time

import jax

BACKEND_COMPILE_EVENT = "/jax/core/compile/backend_compile_duration"
COMPILE_EVENTS = (
    "/jax/core/compile/jaxpr_trace_duration",
    "/jax/core/compile/jaxpr_to_mlir_module_duration",
    BACKEND_COMPILE_EVENT,
)


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
