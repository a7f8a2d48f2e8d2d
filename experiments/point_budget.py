"""Point subsampling and coarse-to-fine as work-saving strategies: accuracy and time
against the number of points the cloud keeps (``InputOptions.max_points``) and the
number the GA scores during the first half of the search (``FitConfig.coarse_points``),
same images, seed and search.

The cost of a fit is linear in the cloud's size (every evaluation measures every
point against every capsule), so halving the points halves the search's
arithmetic; the question is what it costs in accuracy.  For each model, each
point count and each image: one fit with the default ``FitConfig`` (or
``--generations``), scored with the symmetric PCP against the truth.  Then, at the
default ``max_points``, one row per ``--coarse`` count: the same fits with
``coarse_points`` set (the points are the same; only the GA's first half scores fewer).

Writes ``point_budget.{json,md}`` (default ``experiments/results``).  Each point
count compiles once (its first image's time includes the compilation and is left
out of the median).
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys

import common as C
import numpy as np
from machine import now_iso
from outputs import log, write_json, write_text

from jaxpose.pipeline import InputOptions, load_observation
from jaxpose.search import FitConfig

POINTS = (256, 512, 1024, 2048)
COARSE = (256,)


def parse_args(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", nargs="+", default=list(C.MODELS), choices=C.MODELS)
    ap.add_argument("--points", nargs="+", type=int, default=list(POINTS), help="max_points values")
    ap.add_argument("--coarse", nargs="*", type=int, default=list(COARSE),
                    help="FitConfig.coarse_points values tried at the default max_points (none: skip)")
    ap.add_argument("--images", type=int, default=6, help="images per model, spread through the data set")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--generations", type=int, help="FitConfig.generations (default FitConfig's)")
    ap.add_argument("--data", default=C.DATA_DIR, help="data folder (default data/; made if missing)")
    ap.add_argument("--out", default=C.RESULTS_DIR)
    a = ap.parse_args(argv)
    if min(a.points) < 1 or a.images < 1 or min(a.coarse, default=1) < 1:
        ap.error("--points, --coarse and --images must be >= 1")
    return a


def cloud_of(ds, entry, max_points: int):
    opts = dataclasses.replace(C.depth_options(ds, entry), max_points=max_points)
    _, _, cloud = load_observation(os.path.join(ds.folder, entry["image"]), opts)
    return cloud


def main(argv=None) -> int:
    a = parse_args(argv)
    C.ensure_data(a.models, a.data)
    config = FitConfig() if a.generations is None else dataclasses.replace(FitConfig(), generations=a.generations)
    config.validate()
    rows = []
    for model in a.models:
        ds = C.load_dataset(model, a.data)
        entries = C.select_images(ds, a.images)
        runs = [(n, 0) for n in a.points] + [(InputOptions.max_points, c) for c in a.coarse]
        for n, coarse in runs:
            cfg = dataclasses.replace(config, coarse_points=coarse).validate()
            pcp, secs, pts = [], [], []
            for i, e in enumerate(entries):
                base = C.load_image(ds, e)
                img = base._replace(cloud=cloud_of(ds, e, n))
                rec = C.fit_image(ds, img, cfg, a.seed)
                pcp.append(rec["symmetric"]["pcp"])
                pts.append(int(np.sum(np.asarray(img.cloud.weights) > 0)))
                if i > 0 or len(entries) == 1:
                    secs.append(rec["wall_seconds"])
                log(f"{model:9s} max_points {n:5d} coarse {coarse:5d} {e['name']:18s} PCP {pcp[-1]:.3f}  "
                      f"{rec['wall_seconds']:6.2f} s")
            rows.append({"model": model, "max_points": n, "coarse_points": coarse,
                         "points_used": float(np.mean(pts)),
                         "link_accuracy": float(np.mean(pcp)), "seconds_per_image": float(np.median(secs)),
                         "images": len(entries), "seed": a.seed,
                         "generations": cfg.for_skeleton(ds.skeleton).generations})
    out = {"rows": rows, "machine": C.machine_info(), "finished": now_iso()}
    write_json(os.path.join(a.out, "point_budget.json"), out)
    lines = ["| model | max_points | coarse_points (first half) | points used (mean) | link accuracy "
             "| s / image (median, warm) |",
             "|---|---:|---:|---:|---:|---:|"]
    lines += [f"| {r['model']} | {r['max_points']} | {r['coarse_points'] or '– (all)'} | {r['points_used']:.0f} | "
              f"{100 * r['link_accuracy']:.1f}% | {r['seconds_per_image']:.2f} |" for r in rows]
    text = "\n".join(lines) + "\n"
    write_text(os.path.join(a.out, "point_budget.md"), text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
