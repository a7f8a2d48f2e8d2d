"""Peak-memory probes for the benchmark (``bench.py``): each probe is a fresh process
(``bench.py --probe SPEC``) that builds the inputs, then compiles and runs one
implementation once, reading the peak resident set size before, after compiling and
after running, and XLA's scratch size (docs/performance.md).
"""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys

import jax
import jax.numpy as jnp
from bench_kernel import REFERENCE, config_key, kernel_args, kernel_fn, make_problem, naive_args, naive_cost, numpy_cost
from bench_timing import compile_timed

HERE = os.path.dirname(os.path.abspath(__file__))


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
    cmd = [sys.executable, os.path.join(HERE, "bench.py"), "--probe", json.dumps(spec)]
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
