"""The paper's table: branch-swap GA vs hill climbing, at equal evaluation budgets, on
the spider (20 images) and humanoid (32 images) data sets, several seeds; plus the
paper's objective (no free-space term) as its own row.  ``make paper``.

Writes experiments/results/paper_table.{json,csv,md} and paper_figure.png (the
paper's Figure 2: depth image, GA pose, hill-climbing pose).  Every finished fit is
stored under experiments/results/runs/paper/ and skipped on a rerun, so an
interrupted run resumes where it stopped.  See docs/experiments.md.

With several devices or processes (or --devices / --batch) the fits of each row run
as sharded batches over all of them (experiments/sharded.py, docs/scaling.md);
process 0 writes the outputs.
"""

from __future__ import annotations

import argparse
import os
import sys

import common as C
import numpy as np
import sharded
from outputs import log, pyplot, rel, save_figure, write_csv, write_json, write_text

from jaxpose.camera import project

# The rows of the table: name -> FitConfig overrides ("objective": ObjectiveConfig overrides).
# Everything else comes from FitConfig()'s defaults (and --population / --generations).
VARIANTS = {
    "ga": {"algorithm": "ga"},
    "ga-paper-objective": {"algorithm": "ga", "objective": {"free_space_weight": 0.0, "collision_weight": 0.0,
                                                             "sigma_factor": 1.0}},
    "hc": {"algorithm": "hc"},
    "ga-coarse": {"algorithm": "ga", "coarse_points": 256},
}
# Every other variant gets the generation count that brings its evaluation count
# (see --match) closest to this one's.
BUDGET_REFERENCE = "ga"
FIGURE_VARIANTS = ("ga", "hc")  # the columns of the figure (those that were run)

PAPER = {  # the paper's results (GA, one CPU core)
    "spider": {"link_accuracy": 0.99, "minutes_per_image": 30},
    "humanoid": {"link_accuracy": 0.84, "minutes_per_image": 70},
}
QUICK = {"images": 3, "seeds": 1, "population": 64, "generations": 50}

OUT = C.RESULTS_DIR
RUNS = os.path.join(C.RUNS_DIR, "paper")


def parse_args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", nargs="+", default=list(C.MODELS), choices=C.MODELS)
    ap.add_argument("--set", dest="settings", action="append", metavar="NAME=VALUE",
                    help="a FitConfig setting of every row (repeatable; objective.NAME for the cost's), "
                         "as hard_poses.py --set")
    ap.add_argument("--algorithms", nargs="+", default=list(VARIANTS), choices=list(VARIANTS), metavar="ROW",
                    help=f"table rows to run (default: all of {', '.join(VARIANTS)})")
    ap.add_argument("--images", nargs="+", metavar="N|NAME",
                    help="images per model: a count (evenly spread through the data set) or names (default: all)")
    ap.add_argument("--seeds", type=int, help="seeds 0..N-1 per image (default 3)")
    ap.add_argument("--population", type=int, help="FitConfig.population (default: FitConfig's)")
    ap.add_argument("--generations", type=int, help=f"FitConfig.generations of {BUDGET_REFERENCE!r} "
                                                    "(default: FitConfig's)")
    ap.add_argument("--match", choices=("total", "objective", "none"), default="total",
                    help="equalise the budgets of all rows to the GA's: 'total' = objective + gradient "
                         "evaluations (= distance evaluations, default), 'objective' = objective evaluations "
                         "only, 'none' = same generations")
    ap.add_argument("--quick", action="store_true",
                    help=f"smoke run: {QUICK['images']} images per model, {QUICK['seeds']} seed, population "
                         f"{QUICK['population']}, {QUICK['generations']} generations (flags still override); "
                         "outputs go to experiments/results/quick/")
    ap.add_argument("--figure-images", type=int, default=2, help="example images per model in the figure")
    ap.add_argument("--data", default=C.DATA_DIR, help="data folder (default data/; made if missing)")
    ap.add_argument("--out", help="output folder (default experiments/results, --quick: experiments/results/quick)")
    sharded.add_arguments(ap)
    args = ap.parse_args(argv)
    q = QUICK if args.quick else {"images": None, "seeds": 3, "population": None, "generations": None}
    args.images = C.parse_images_arg(args.images) if args.images else q["images"]
    for name in ("seeds", "population", "generations"):
        if getattr(args, name) is None:
            setattr(args, name, q[name])
    if args.seeds < 1:
        ap.error("--seeds must be >= 1")
    if args.settings and not args.out:
        ap.error("--set needs --out: the default folder holds the table of the default settings")
    args.out = args.out or (os.path.join(OUT, "quick") if args.quick else OUT)
    return args


def variant_configs(args, skel) -> tuple[dict, dict]:
    """FitConfig of every selected row for one model's skeleton (generations resolved for
    it, budgets matched to BUDGET_REFERENCE) and the budget info."""
    from hard_poses import config_with, parse_settings

    base = config_with(parse_settings(args.settings))
    over = {k: v for k, v in (("population", args.population), ("generations", args.generations)) if v is not None}
    base = C.make_config(base, over).for_skeleton(skel)
    ref = C.make_config(base, VARIANTS[BUDGET_REFERENCE])
    target = C.planned_evaluations(ref, skel=skel)
    configs = {}
    for name in args.algorithms:
        cfg = C.make_config(base, VARIANTS[name])
        if name != BUDGET_REFERENCE:
            cfg = C.match_generations(cfg, target, args.match, skel)
        configs[name] = cfg
    planned = {n: C.planned_evaluations(c, skel=skel) for n, c in configs.items()}
    budget = {"reference_planned": target, "planned": planned}
    return configs, budget


def run_fits(args, datasets, images, configs) -> tuple[dict, C.FitRunner]:
    """Every (model, row, seed, image) fit, through the run store; returns records[model][row]."""
    seeds = list(range(args.seeds))
    total = sum(len(images[m]) * len(configs[m]) for m in datasets) * len(seeds)
    runner = C.FitRunner(C.RunStore(RUNS), total)
    log(f"{total} fits: models {', '.join(datasets)}; rows {', '.join(args.algorithms)}; seeds {seeds}; "
          + "; ".join(f"{m} {n}: P={c.population} G={c.generations}" for m in datasets for n, c in configs[m].items()))
    records: dict = {m: {n: [] for n in configs[m]} for m in datasets}
    batches = sharded.BatchRunner(runner, args.devices, args.batch) if sharded.enabled(args) else None
    for m, ds in datasets.items():
        for name, cfg in configs[m].items():
            if batches is not None:
                records[m][name] = batches.run(ds, images[m], name, cfg, seeds)
                continue
            for seed in seeds:
                for entry in images[m]:
                    records[m][name].append(runner.run(ds, entry, name, cfg, seed))
    if runner.skipped:
        log(f"{runner.skipped} of {total} fits were stored already ({rel(RUNS)}) and skipped")
    return records, runner


def summarise(records, runner, datasets, configs) -> dict:
    out: dict = {}
    for m, rows in records.items():
        out[m] = {}
        for name, recs in rows.items():
            acc = C.seed_stats(recs, lambda r: r["symmetric"]["pcp"])
            warm = runner.warmup_record(datasets[m], name, configs[m][name])
            evals = sorted({r["objective_evaluations"] for r in recs})
            grads = sorted({r["gradient_evaluations"] for r in recs})
            out[m][name] = {
                "link_accuracy": acc["mean"],
                "link_accuracy_std": acc["std"],
                "link_accuracy_per_seed": acc["per_seed"],
                "link_accuracy_strict": C.mean_scored(r["strict"]["pcp"] for r in recs),
                "pcp_10cm": C.mean_scored(r["symmetric"]["pcp_10cm"] for r in recs),
                "pck_10cm": C.mean_scored(r["symmetric"]["pck_10cm"] for r in recs),
                "mpjpe_mm": C.mean_scored(r["symmetric"]["mpjpe_mm"] for r in recs),
                "strict": {k: C.mean_scored(r["strict"][k] for r in recs) for k in C.METRICS},
                "seconds_per_image": float(np.median([r["wall_seconds"] for r in recs])),
                "compile_seconds": C.compile_seconds(warm, recs),
                "evaluations": evals[0] if len(evals) == 1 else evals,
                "gradient_evaluations": grads[0] if len(grads) == 1 else grads,
                "distance_evaluations": float(np.median([r["distance_evaluations"] for r in recs])),
                "population": configs[m][name].population,
                "generations": configs[m][name].generations,
                "images": len({r["image"] for r in recs}),
                "seeds": len({r["seed"] for r in recs}),
                "fits": len(recs),
            }
    return out


def pct(x, std=None):
    if x is None:
        return "–"
    return f"{100 * x:.1f}%" + (f" ± {100 * std:.1f}" if std is not None else "")


def markdown(table, machine, budget, args) -> str:
    lines = [
        "# Paper table: GA vs hill climbing",
        "",
        f"Machine: {machine['cpu']}, {machine['cores_usable']} cores usable, JAX {machine['jax']} "
        f"({machine['backend']}), {machine['date']}.  Seeds: {args.seeds}; budgets matched on "
        f"{budget['match']} evaluations to `{budget['reference']}`.  Generated by `experiments/paper_table.py`"
        + (" --quick (not a real result)" if args.quick else "") + ".",
        "",
        "Link accuracy = symmetric PCP (mean over images and seeds; ± std over seeds of the per-seed mean). "
        "Time = median wall time per image without compilation.",
        "",
        "| model | method | link accuracy | strict PCP | PCP@10cm | PCK@10cm | MPJPE (mm) | s / image "
        "| compile (s) | evaluations (obj + grad) | images x seeds |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for m, rows in table.items():
        p = PAPER.get(m)
        if p:
            lines.append(f"| {m} | paper (GA, 1 core) | {pct(p['link_accuracy'])} | – | – | – | – | "
                         f"{60 * p['minutes_per_image']} ({p['minutes_per_image']} min) | – | – | – |")
        for name, r in rows.items():
            cs = "–" if r["compile_seconds"] is None else f"{r['compile_seconds']:.0f}"
            lines.append(
                f"| {m} | {name} | {pct(r['link_accuracy'], r['link_accuracy_std'])} | "
                f"{pct(r['link_accuracy_strict'])} | {pct(r['pcp_10cm'])} | {pct(r['pck_10cm'])} | "
                f"{r['mpjpe_mm']:.0f} | {r['seconds_per_image']:.2f} | {cs} | "
                f"{r['evaluations']} + {r['gradient_evaluations']} | {r['images']} x {r['seeds']} |")
    lines.append("")
    return "\n".join(lines)


CSV_COLUMNS = ["model", "image", "label", "algorithm", "seed", *C.CSV_METRIC_COLUMNS, "wall_seconds",
               "objective_evaluations", "gradient_evaluations", "distance_evaluations", "population",
               "generations", "cost", "inclination_deg", "occluded_links"]


def figure(path, records, datasets, images, n_per_model):
    """Depth image with the poses of FIGURE_VARIANTS (seed 0) over it; truth as a thin black line."""
    plt = pyplot()
    cols = [v for v in FIGURE_VARIANTS if any(records[m].get(v) for m in records)]
    cols = cols or [v for v in VARIANTS if any(records[m].get(v) for m in records)]
    examples = []
    for m in records:
        examples += [(m, e) for e in C.spread(images[m], n_per_model)]
    if not examples or not cols:
        return False
    fig, axes = plt.subplots(len(examples), 1 + len(cols), figsize=(3.2 * (1 + len(cols)), 2.6 * len(examples)),
                             squeeze=False)
    for row, (m, entry) in enumerate(examples):
        ds = datasets[m]
        img = C.load_image(ds, entry)
        k = img.intrinsics
        shown = np.where(img.depth > 0, img.depth, np.nan)
        truth_uv = [project(np.array([s, e]), k) for s, e in zip(img.truth["start"], img.truth["end"])]
        pts = [np.concatenate(truth_uv)]
        fits = {}
        for v in cols:
            rec = next((r for r in records[m].get(v, []) if r["image"] == entry["name"] and r["seed"] == 0), None)
            if rec is not None:
                uv = [project(np.array([s, e]), k) for s, e in zip(rec["links"]["start"], rec["links"]["end"])]
                fits[v] = (rec, uv)
                pts.append(np.concatenate(uv))
        lo = np.min(np.concatenate(pts), 0)
        hi = np.max(np.concatenate(pts), 0)
        pad = 0.15 * np.max(hi - lo) + 10
        xlim = (max(0, lo[0] - pad), min(k.width, hi[0] + pad))
        ylim = (min(k.height, hi[1] + pad), max(0, lo[1] - pad))
        cmap = plt.get_cmap("tab20")
        for c, v in enumerate([None, *cols]):
            ax = axes[row, c]
            ax.imshow(shown, cmap="gray_r")
            ax.set_xlim(*xlim)
            ax.set_ylim(*ylim)
            ax.set_xticks([])
            ax.set_yticks([])
            if v is None:
                ax.set_title(f"{m} {entry['name']}", fontsize=8)
                continue
            if v not in fits:
                ax.set_title(f"{v}: not run", fontsize=8)
                continue
            rec, uv = fits[v]
            for i, seg in enumerate(uv):
                ax.plot(seg[:, 0], seg[:, 1], "-", color=cmap(i % 20), lw=2.5, solid_capstyle="round")
            for seg in truth_uv:
                ax.plot(seg[:, 0], seg[:, 1], "-", color="k", lw=0.7)
            ax.set_title(f"{v}: PCP {rec['symmetric']['pcp']:.2f}", fontsize=8)
    fig.suptitle("depth image; fitted links (colour) and truth (thin black), seed 0", fontsize=9)
    fig.tight_layout()
    save_figure(fig, path)
    return True


def main(argv=None) -> int:
    args = parse_args(argv)
    C.ensure_data(args.models, args.data)
    datasets = {m: C.load_dataset(m, args.data) for m in args.models}
    configs, budget = {}, {"match": args.match, "reference": BUDGET_REFERENCE, "reference_planned": {}, "planned": {}}
    for m, ds in datasets.items():  # the default generations depend on the skeleton (FitConfig.for_skeleton)
        configs[m], b = variant_configs(args, ds.skeleton)
        budget["reference_planned"][m], budget["planned"][m] = b["reference_planned"], b["planned"]
    images = {m: C.select_images(ds, args.images) for m, ds in datasets.items()}
    try:
        records, runner = run_fits(args, datasets, images, configs)
    except KeyboardInterrupt:
        log(f"\ninterrupted: every finished fit is stored in {rel(RUNS)}; run the same command to resume")
        return 130
    if not sharded.is_main_process():
        return 0
    table = summarise(records, runner, datasets, configs)
    machine = C.machine_info()
    machines = sorted({r["machine"] for rows in records.values() for recs in rows.values() for r in recs})
    if len(machines) > 1:
        log(f"warning: the stored fits come from {len(machines)} machines: {machines} (timings mix)")
    doc = {
        "title": "GA vs hill climbing at equal evaluation budgets (jaxpose reproduction of the paper's table)",
        "quick": args.quick,
        "machine": machine,
        "machines_in_runs": machines,
        "data": {m: {"folder": rel(ds.folder), "index_sha256": ds.fingerprint, "seed": ds.index.get("seed"),
                     "images": [e["name"] for e in images[m]]} for m, ds in datasets.items()},
        "seeds": list(range(args.seeds)),
        "budget": budget,
        "config": {
            "variants": {n: VARIANTS[n] for n in args.algorithms},
            "fit_config": {m: {n: c.to_dict() for n, c in configs[m].items()} for m in configs},
            "depth_options": {m: C.depth_options_record(ds) for m, ds in datasets.items()},
        },
        "paper": PAPER,
        "results": table,
    }
    os.makedirs(args.out, exist_ok=True)
    paths = {x: os.path.join(args.out, f"paper_table.{x}") for x in ("json", "csv", "md")}
    write_json(paths["json"], doc)
    rows = [C.flat_row(r) for rows in records.values() for recs in rows.values() for r in recs]
    write_csv(paths["csv"], rows, CSV_COLUMNS)
    write_text(paths["md"], markdown(table, machine, budget, args))
    fig_path = os.path.join(args.out, "paper_figure.png")
    made = figure(fig_path, records, datasets, images, args.figure_images)
    log("")
    log(markdown(table, machine, budget, args))
    log("wrote " + ", ".join(rel(p) for p in [*paths.values(), *([fig_path] if made else [])]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
