"""Population sweep: accuracy against population size at a fixed evaluation budget and
at a fixed wall-time budget, on a few images per model, several seeds.

- fixed evaluations: ``generations = budget // population`` (budget default:
  FitConfig's population x 300 generations, the humanoid's default fit, for every model);
- fixed wall time: each population gets the generation count that makes a fit take
  about ``T`` seconds on this machine, from a timing probe (its fixed-evaluation fits:
  per-generation time and fixed cost read off the fit's progress callbacks; see
  docs/experiments.md).  ``T`` defaults to the measured time of the default
  population at the fixed budget.

Writes experiments/results/sweep_population.{csv,json,png}.  Every finished fit is
stored under experiments/results/runs/sweep/ and skipped on a rerun.

With several devices or processes (or --devices / --batch) the fixed-evaluation fits
run as sharded batches over all of them (experiments/sharded.py, docs/scaling.md);
the fixed-wall-time mode times single fits, so it runs them one by one; process 0
writes the outputs.
"""

from __future__ import annotations

import argparse
import math
import os
import sys

import common as C
import numpy as np
import sharded
from machine import machine_id
from outputs import log, pyplot, rel, save_figure, write_csv, write_json

from jaxpose.search import FitConfig

POPULATIONS = (16, 64, 256, 1024, 4096)  # powers of 4
MODES = ("evals", "time")
DEFAULT_GENERATIONS = 300  # FitConfig's automatic count for the humanoid (its maximum)
QUICK = {"populations": (16, 64, 256), "images": 2, "seeds": 1, "budget": 64 * 50}

OUT = C.RESULTS_DIR
RUNS = os.path.join(C.RUNS_DIR, "sweep")


def parse_args(argv=None):
    d = FitConfig()
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", nargs="+", default=list(C.MODELS), choices=C.MODELS)
    ap.add_argument("--algorithms", nargs="+", default=["ga"], choices=("ga", "hc"))
    ap.add_argument("--populations", nargs="+", type=int, help=f"default {' '.join(map(str, POPULATIONS))}")
    ap.add_argument("--modes", nargs="+", default=list(MODES), choices=MODES,
                    help="evals: fixed evaluation budget; time: fixed wall time (default both)")
    ap.add_argument("--budget", type=int, help=f"objective evaluations of the generations, population x "
                                               f"generations (default {d.population} x {DEFAULT_GENERATIONS}, "
                                               "the humanoid's default fit)")
    ap.add_argument("--seconds", type=float,
                    help="wall-time budget T per fit (default: the median wall time of the fixed-budget fits "
                         f"at the population nearest {d.population}, per model)")
    ap.add_argument("--islands", type=int, default=d.islands,
                    help=f"islands per fit; the population and the budget are per island (default {d.islands}; "
                         "1: one population, as in the paper)")
    ap.add_argument("--images", nargs="+", metavar="N|NAME", help="images per model: a count or names (default 4)")
    ap.add_argument("--seeds", type=int, help="seeds 0..N-1 (default 3)")
    ap.add_argument("--quick", action="store_true",
                    help=f"smoke run: populations {' '.join(map(str, QUICK['populations']))}, {QUICK['images']} "
                         f"images, {QUICK['seeds']} seed, budget {QUICK['budget']} (flags still override); "
                         "outputs go to experiments/results/quick/")
    ap.add_argument("--data", default=C.DATA_DIR)
    ap.add_argument("--out", help="output folder (default experiments/results, --quick: experiments/results/quick)")
    sharded.add_arguments(ap)
    args = ap.parse_args(argv)
    q = QUICK if args.quick else {"populations": POPULATIONS, "images": 4, "seeds": 3,
                                  "budget": d.population * DEFAULT_GENERATIONS}
    args.populations = sorted(set(args.populations or q["populations"]))
    args.images = C.parse_images_arg(args.images) if args.images else q["images"]
    args.seeds = args.seeds if args.seeds is not None else q["seeds"]
    args.budget = args.budget if args.budget is not None else q["budget"]
    if args.seeds < 1 or args.budget < 1 or args.islands < 1 or min(args.populations) < 2:
        ap.error("--seeds, --budget, --islands must be >= 1 and populations >= 2")
    args.out = args.out or (os.path.join(OUT, "quick") if args.quick else OUT)
    return args


def evals_config(algorithm: str, population: int, budget: int, islands: int = FitConfig.islands) -> FitConfig:
    return C.make_config(FitConfig(), {"algorithm": algorithm, "population": population,
                                       "generations": max(1, budget // population), "islands": islands})


def timing_model(rec: dict) -> tuple[float, float]:
    """``(seconds per generation, fixed seconds)`` of a warm fit, from its progress callbacks.

    With two or more callbacks, the time per generation is the time between the first
    and the last callback over the generations between them (memetic steps included,
    as they recur every epoch); with one, the time to it over its generation count (the
    first generation evaluates the initial population).  The fixed part (initial
    population, final refinement, the Python loop) is the rest of the fit's time.
    """
    ts, G = rec["epoch_times"], rec["generations"]
    if len(ts) >= 2 and ts[-1][0] > ts[0][0]:
        tau = (ts[-1][1] - ts[0][1]) / (ts[-1][0] - ts[0][0])
    else:
        tau = ts[-1][1] / max(ts[-1][0], 1)
    return tau, max(0.0, rec["wall_seconds"] - G * tau)


def generations_for(seconds: float, tau: float, fixed: float) -> int:
    return max(1, int(math.floor((seconds - fixed) / max(tau, 1e-9))))


class Sweep:
    def __init__(self, args):
        self.args = args
        self.store = C.RunStore(RUNS)
        self.seeds = list(range(args.seeds))
        C.ensure_data(args.models, args.data)
        self.datasets = {m: C.load_dataset(m, args.data) for m in args.models}
        self.images = {m: C.select_images(ds, args.images) for m, ds in self.datasets.items()}
        per_cfg = sum(len(v) for v in self.images.values()) * len(self.seeds)
        total = per_cfg * len(args.populations) * len(args.modes) * len(args.algorithms)
        self.runner = C.FitRunner(self.store, total)
        self.rows: list[dict] = []  # (mode, record) pairs as dicts
        self.plans: dict = {}
        self.batches = sharded.BatchRunner(self.runner, args.devices, args.batch) if sharded.enabled(args) else None

    def fits(self, ds, algorithm, population, config, mode, extra) -> list[dict]:
        if self.batches is not None and mode == "evals":  # the time mode times single fits
            out = self.batches.run(ds, self.images[ds.model], f"{algorithm}-P{population}", config, self.seeds)
            self.rows += [{"mode": mode, **extra, "record": rec} for rec in out]
            return out
        out = []
        for seed in self.seeds:
            for entry in self.images[ds.model]:
                rec = self.runner.run(ds, entry, f"{algorithm}-P{population}", config, seed)
                out.append(rec)
                self.rows.append({"mode": mode, **extra, "record": rec})
        return out

    def probe(self, ds, algorithm, population) -> list[dict]:
        """Warm fixed-budget fits of this population (runs the first one when none is stored)."""
        cfg = evals_config(algorithm, population, self.args.budget, self.args.islands)
        recs = [self.store.get(self.runner.keys(ds, e["name"], f"{algorithm}-P{population}", cfg, s)[0])
                for s in self.seeds for e in self.images[ds.model]]
        recs = [r for r in recs if r]
        if not recs:
            self.runner.total += 1
            recs = [self.runner.run(ds, self.images[ds.model][0], f"{algorithm}-P{population}", cfg, self.seeds[0])]
        return recs

    def target_seconds(self, ds, algorithm) -> tuple[float, dict]:
        if self.args.seconds is not None:
            return self.args.seconds, {"given": True}
        d = FitConfig().population
        p_ref = min(self.args.populations, key=lambda p: (abs(math.log(p / d)), p))
        cfg = evals_config(algorithm, p_ref, self.args.budget, self.args.islands)
        key = C.run_key("plan", ds.model, algorithm, "seconds-auto", C.run_fingerprint(ds, cfg))
        plan = self.store.get(key)
        if plan is None:
            recs = self.probe(ds, algorithm, p_ref)
            plan = {"seconds": float(np.median([r["wall_seconds"] for r in recs])), "population": p_ref,
                    "generations": cfg.generations, "from_fits": len(recs), "machine": machine_id()}
            self.store.put(key, plan)
        return plan["seconds"], plan

    def time_config(self, ds, algorithm, population, seconds, splan) -> tuple[FitConfig, dict]:
        cfg_a = evals_config(algorithm, population, self.args.budget, self.args.islands)
        if splan.get("population") == population:  # T is this population's own time at the fixed budget
            return cfg_a, {"seconds": seconds, "generations": cfg_a.generations, "reference": True}
        key = C.run_key("plan", ds.model, algorithm, f"P{population}", f"T{seconds:.6g}",
                        C.run_fingerprint(ds, cfg_a))
        plan = self.store.get(key)
        if plan is None:
            recs = self.probe(ds, algorithm, population)
            tau, fixed = (float(np.median(x)) for x in zip(*map(timing_model, recs)))
            plan = {"seconds": seconds, "seconds_per_generation": tau, "fixed_seconds": fixed,
                    "generations": generations_for(seconds, tau, fixed), "from_fits": len(recs),
                    "machine": machine_id()}
            self.store.put(key, plan)
            log(f"         {ds.model:<8} {algorithm}-P{population}: {1000 * tau:.2f} ms/generation + "
                  f"{fixed:.2f} s fixed -> {plan['generations']} generations for {seconds:.2f} s")
        return C.make_config(cfg_a, {"generations": plan["generations"]}), plan

    def run(self):
        a = self.args
        log(f"{self.runner.total} fits: models {', '.join(a.models)}; algorithms {', '.join(a.algorithms)}; "
              f"populations {a.populations} x {a.islands} island(s); modes {', '.join(a.modes)}; "
              f"budget {a.budget}; "
              f"{len(self.seeds)} seed(s)")
        for m, ds in self.datasets.items():
            for alg in a.algorithms:
                if "evals" in a.modes:
                    for p in a.populations:
                        cfg = evals_config(alg, p, a.budget, a.islands)
                        self.fits(ds, alg, p, cfg, "evals", {"budget": a.budget})
                if "time" in a.modes:
                    seconds, splan = self.target_seconds(ds, alg)
                    self.plans[f"{m}/{alg}/seconds"] = splan
                    for p in a.populations:
                        cfg, plan = self.time_config(ds, alg, p, seconds, splan)
                        self.plans[f"{m}/{alg}/P{p}"] = plan
                        self.fits(ds, alg, p, cfg, "time", {"target_seconds": seconds})
        if self.runner.skipped:
            log(f"{self.runner.skipped} fits were stored already ({rel(RUNS)}) and skipped")


def aggregate(sweep: Sweep) -> list[dict]:
    groups: dict = {}
    for row in sweep.rows:
        r = row["record"]
        groups.setdefault((row["mode"], r["model"], r["algorithm"], r["population"]), []).append(row)
    out = []
    for (mode, model, alg, p), rows in sorted(groups.items()):
        recs = [x["record"] for x in rows]
        acc = C.seed_stats(recs, lambda r: r["symmetric"]["pcp"])
        ds = sweep.datasets[model]
        cfg = C.make_config(evals_config(alg, p, sweep.args.budget, sweep.args.islands),
                            {"generations": recs[0]["generations"]})
        out.append({
            "mode": mode, "model": model, "algorithm": alg, "population": p, "islands": sweep.args.islands,
            "generations": recs[0]["generations"],
            "budget": rows[0].get("budget"), "target_seconds": rows[0].get("target_seconds"),
            "link_accuracy": acc["mean"], "link_accuracy_std": acc["std"],
            "link_accuracy_strict": C.mean_scored(r["strict"]["pcp"] for r in recs),
            "pcp_10cm": C.mean_scored(r["symmetric"]["pcp_10cm"] for r in recs),
            "mpjpe_mm": C.mean_scored(r["symmetric"]["mpjpe_mm"] for r in recs),
            "seconds_per_image": float(np.median([r["wall_seconds"] for r in recs])),
            "compile_seconds": C.compile_seconds(sweep.runner.warmup_record(ds, f"{alg}-P{p}", cfg), recs),
            "objective_evaluations": int(np.median([r["objective_evaluations"] for r in recs])),
            "gradient_evaluations": int(np.median([r["gradient_evaluations"] for r in recs])),
            "fits": len(recs),
        })
    return out


CSV_COLUMNS = ["mode", "model", "algorithm", "population", "generations", "image", "seed", *C.CSV_METRIC_COLUMNS,
               "wall_seconds", "objective_evaluations", "gradient_evaluations", "distance_evaluations", "budget",
               "target_seconds", "inclination_deg", "occluded_links"]


def plot(path, summary, models):
    plt = pyplot()
    from matplotlib.ticker import FormatStrFormatter

    fig, axes = plt.subplots(len(models), 2, figsize=(10, 3.6 * len(models)), squeeze=False)
    styles = {"evals": ("o-", "fixed evaluations"), "time": ("s--", "fixed wall time")}
    for i, m in enumerate(models):
        ax_p, ax_t = axes[i]
        for (mode, alg) in sorted({(s["mode"], s["algorithm"]) for s in summary if s["model"] == m}):
            rows = sorted((s for s in summary if s["model"] == m and s["mode"] == mode and s["algorithm"] == alg),
                          key=lambda s: s["population"])
            fmt, what = styles[mode]
            extra = (f"{rows[0]['budget']} evals" if mode == "evals" else f"{rows[0]['target_seconds']:.2f} s")
            label = f"{alg}, {what} ({extra})"
            pops = [s["population"] for s in rows]
            acc = [100 * s["link_accuracy"] for s in rows]
            err = [100 * (s["link_accuracy_std"] or 0) for s in rows]
            secs = [s["seconds_per_image"] for s in rows]
            line = ax_p.errorbar(pops, acc, yerr=err, fmt=fmt, capsize=3, label=label)
            ax_t.errorbar(secs, acc, yerr=err, fmt=fmt, capsize=3, color=line[0].get_color(), label=label)
            for x, y, p in zip(secs, acc, pops):
                ax_t.annotate(f"P={p}", (x, y), textcoords="offset points", xytext=(4, 4), fontsize=7)
        pops = sorted({s["population"] for s in summary if s["model"] == m})
        ax_p.set_xscale("log", base=2)
        ax_p.set_xticks(pops, [str(p) for p in pops])
        ax_p.minorticks_off()
        ax_p.set_xlabel("population")
        for t in sorted({s["target_seconds"] for s in summary if s["model"] == m and s["mode"] == "time"}):
            ax_t.axvline(t, color="grey", ls=":", lw=1)
        ax_t.set_xscale("log")
        ax_t.xaxis.set_major_formatter(FormatStrFormatter("%g"))
        ax_t.xaxis.set_minor_formatter(FormatStrFormatter("%g"))
        ax_t.tick_params(axis="x", which="minor", labelsize=7)
        ax_t.set_xlabel("median wall time per fit (s, compilation excluded)")
        for ax in (ax_p, ax_t):
            ax.set_ylabel(f"{m}: link accuracy (sym. PCP, %)")
            ax.grid(alpha=0.3)
        ax_p.legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, path)


def main(argv=None) -> int:
    args = parse_args(argv)
    sweep = Sweep(args)
    try:
        sweep.run()
    except KeyboardInterrupt:
        log(f"\ninterrupted: every finished fit is stored in {rel(RUNS)}; run the same command to resume")
        return 130
    if not sharded.is_main_process():
        return 0
    summary = aggregate(sweep)
    os.makedirs(args.out, exist_ok=True)
    paths = {x: os.path.join(args.out, f"sweep_population.{x}") for x in ("csv", "json", "png")}
    rows = [{**C.flat_row(x["record"]), "mode": x["mode"], "budget": x.get("budget"),
             "target_seconds": x.get("target_seconds")} for x in sweep.rows]
    write_csv(paths["csv"], rows, CSV_COLUMNS)
    write_json(paths["json"], {
        "title": "population sweep at a fixed evaluation budget and at a fixed wall time",
        "quick": args.quick,
        "machine": C.machine_info(),
        "machines_in_runs": sorted({x["record"]["machine"] for x in sweep.rows}),
        "budget": args.budget,
        "populations": args.populations,
        "seeds": sweep.seeds,
        "images": {m: [e["name"] for e in v] for m, v in sweep.images.items()},
        "base_config": FitConfig().to_dict(),
        "plans": sweep.plans,
        "summary": summary,
    })
    plot(paths["png"], summary, args.models)
    log("")
    log(f"{'mode':<6} {'model':<9} {'alg':<4} {'P':>5} {'G':>6} {'accuracy':>14} {'s/fit':>7} {'evals':>14}")
    for s in summary:
        std = "" if s["link_accuracy_std"] is None else f" ± {100 * s['link_accuracy_std']:.1f}"
        log(f"{s['mode']:<6} {s['model']:<9} {s['algorithm']:<4} {s['population']:>5} {s['generations']:>6} "
              f"{100 * s['link_accuracy']:>6.1f}%{std:<7} {s['seconds_per_image']:>7.2f} "
              f"{s['objective_evaluations']:>7}+{s['gradient_evaluations']:<6}")
    log("wrote " + ", ".join(rel(p) for p in paths.values()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
