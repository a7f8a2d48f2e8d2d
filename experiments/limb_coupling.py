"""Are the hard poses' wrong limbs wrong one at a time, or in pairs?

A diagnosis of stored fits (``hard_poses.py --diagnose``; no search here).  For every
search failure whose root lies within ``--max-root-deg`` of the truth (the trunk right,
limbs wrong), the found capsules are matched to the truth's (symmetric matching), and
every link's subtree that holds a missed link is put where the truth has it, first alone
(the rest as found), then two disjoint such subtrees together.  Each substitution is
scored by the fit's objective on the fit's cloud (``population_cost``).

- a single subtree that lowers the cost: a limb-at-a-time move (the limb sweep) could
  have found it;
- no single one, but a pair: the limbs are coupled (one holds the points of the other),
  and only a move of both at once leaves the basin.

    python experiments/limb_coupling.py experiments/results/hard_poses/diagnosis-default-seen-baseline.json
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
for _p in (ROOT, HERE):
    if _p not in sys.path:
        sys.path.insert(0, _p)

import numpy as np  # noqa: E402


def substitutions(skel, missed: np.ndarray) -> list[tuple[str, list[int]]]:
    """``(label, links)``: every subtree holding a missed link, and every disjoint pair of them."""
    singles = [(skel.link_names[k], sorted(skel.subtree(k))) for k in range(1, skel.num_links)
               if missed[sorted(skel.subtree(k))].any()]
    pairs = [(f"{a}+{b}", sorted(la + lb)) for (a, la), (b, lb) in itertools.combinations(singles, 2)
             if not set(la) & set(lb)]
    return singles + pairs


def analyse(ds, entry: dict, record: dict, config) -> dict:
    import common
    import jax.numpy as jnp

    from jaxpose.io.truth import read_pose
    from jaxpose.kinematics import forward_kinematics
    from jaxpose.metrics import evaluate
    from jaxpose.objective import observe, population_cost
    from jaxpose.search.cost import objective_pairs

    skel = ds.skeleton
    config = config.for_skeleton(skel)
    img = common.load_image(ds, entry)
    tl = forward_kinematics(skel, read_pose(os.path.join(ds.folder, entry["truth"]), skel))
    ts, te, tr = (np.asarray(x, np.float64) for x in (tl.start, tl.end, tl.radius))
    found = record["found_links"]
    ps, pe, pr = (np.asarray(found[k], np.float64) for k in ("start", "end", "radius"))
    ev = evaluate(ps, pe, ts, te, skel)
    idx = {n: i for i, n in enumerate(skel.link_names)}
    perm = np.array([idx[ev["matching"][n]] for n in skel.link_names])
    ps, pe, pr = ps[perm], pe[perm], pr[perm]  # found capsules in the truth's link order
    missed = np.array([ln["scored"] and not ln["correct"] for ln in record["links"]])
    subs = substitutions(skel, missed)
    S, E, R = [ps], [pe], [pr]
    for _, links in subs:
        s, e, r = ps.copy(), pe.copy(), pr.copy()
        s[links], e[links], r[links] = ts[links], te[links], tr[links]
        S.append(s), E.append(e), R.append(r)
    obj = config.objective
    f32 = lambda a: jnp.asarray(np.stack(a), jnp.float32)  # noqa: E731
    costs = np.asarray(population_cost(observe(img.cloud, obj), f32(S), f32(E), f32(R), obj,
                                       pairs=objective_pairs(skel, obj)))
    base = float(costs[0])
    deltas = {label: float(c - base) for (label, _), c in zip(subs, costs[1:])}
    singles = {k: v for k, v in deltas.items() if "+" not in k}
    pairs = {k: v for k, v in deltas.items() if "+" in k}
    return {"image": record["image"], "pcp": record["pcp"], "root_error_deg": record["root_error_deg"],
            "found_cost": base, "truth_cost": record["truth_cost"],
            "missed": [n for n, m in zip(skel.link_names, missed) if m],
            "best_single": min(singles.items(), key=lambda kv: kv[1]) if singles else None,
            "best_pair": min(pairs.items(), key=lambda kv: kv[1]) if pairs else None,
            "singles_lowering": sorted(k for k, v in singles.items() if v < 0)}


def main(argv=None) -> int:
    import hard_poses as H

    from jaxpose.search import FitConfig

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("summary", help="a hard_poses.py summary (.json) whose records hold the found capsules")
    ap.add_argument("--max-root-deg", type=float, default=45.0)
    ap.add_argument("--data", default=H.DATA_DIR)
    args = ap.parse_args(argv)
    doc = json.load(open(args.summary))
    # the search's settings as stored; the objective is today's default (a stored record may name settings of a
    # variant since removed), so score only records of the default objective
    config = FitConfig(**{k: v for k, v in doc["config"].items() if k not in ("objective",)})
    draw = "reference" if "reference" in os.path.basename(args.summary) else "tuning"
    data, rows = {}, []
    for rec in doc["records"]:
        if rec["verdict"] != "search" or rec["root_error_deg"] > args.max_root_deg:
            continue
        name = rec["set"].rsplit("-", 1)[0]
        if name not in data:
            data[name] = H.load_set(name, draw, args.data)
        ds = data[name]
        entry = next(e for e in ds.entries if e["name"] == rec["image"])
        row = analyse(ds, entry, rec, config)
        rows.append(row)
        single, pair = row["best_single"], row["best_pair"]
        print(f"{row['image']:<11} PCP {100 * row['pcp']:5.1f}%  root {row['root_error_deg']:5.1f} deg  "
              f"missed {','.join(row['missed'])}\n    best single {single[0]} {single[1]:+.4f}"
              + (f"   best pair {pair[0]} {pair[1]:+.4f}" if pair else "")
              + f"   singles lowering: {', '.join(row['singles_lowering']) or 'none'}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
