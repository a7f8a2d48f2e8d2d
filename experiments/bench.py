"""Benchmark harness: objective throughput, end-to-end fit speed, peak memory (``make bench``).

Three parts, each in its own module:

- objective throughput (``bench_kernel.py``): the data term as jaxpose's streaming
  kernel, a naive ``jax.vmap`` and a NumPy loop, in point-to-capsule distance
  evaluations per second, compiled / warmed up first (compile time reported
  separately), then timed side by side in rounds (``bench_timing.py``) so that the
  machine's drift falls on all three alike; a throughput is the median of its calls,
  a ratio the median of the rounds' ratios, with their spread over the rounds beside
  it.  NumPy and the naive version run on the first ``P'`` individuals when the whole
  population would take too long (NumPy: ``--numpy-seconds``) or too much memory
  (naive: ``--naive-max-mb``); their throughput is linear in ``P`` and is reported as
  measured, marked ``*``;
- end to end (``bench_e2e.py``): fits of rendered spider / humanoid images with the
  public search, compile time apart from run time, and link accuracy after every
  epoch, so that the time to reach an accuracy can be read;
- peak memory (``bench_memory.py``): each probe runs in a fresh subprocess; see
  ``docs/performance.md``.

This module runs them, keeps the results file and writes the report.

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
import json
import os
import resource
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
for _p in (REPO, HERE):  # run as a script from anywhere without installing; the bench_* modules
    if _p not in sys.path:
        sys.path.insert(0, _p)

from bench_e2e import E2E_PRESETS, run_e2e  # noqa: E402
from bench_kernel import (  # noqa: E402
    REFERENCE,
    SKELETONS,
    TOLERANCE,
    config_key,
    config_line,
    measure_config,
    ratio_ranges,
)
from bench_memory import memory_probes, probe_key, probe_main, run_probe  # noqa: E402
from machine import load_average, machine_info, machine_line, now_iso  # noqa: E402
from outputs import clean, fmt, fmt_rate, log, write_json, write_text  # noqa: E402

from jaxpose.objective import ObjectiveConfig  # noqa: E402

SCHEMA = 1
GRIDS = {
    "full": dict(P=(64, 256, 1024, 4096), N=(512, 2048, 8192, 32768), L=(8, 17, 40)),
    "small": dict(P=(64, 1024), N=(512, 2048, 8192), L=(8, 17, 40)),
    "quick": dict(P=(1024,), N=(2048,), L=(17,)),
}


# --------------------------------------------------------------------------- report


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

    machine = machine_info(load_average_start=load_average())
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
        results["machine"]["load_average_end"] = load_average()
        results["machine"]["peak_rss_mib"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        results["headline"] = headline(results)
        results.update(results["headline"])  # the headline numbers also at the top level
        write_json(args.json, results)
        write_text(args.md, markdown(results))

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
            rec["load_average"] = load_average()
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
