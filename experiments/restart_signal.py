"""Which signal, after one round of searches, says that a second round would help?

Per image, a fit with ``--restarts 2`` (other settings as given) is run with every
search's answer kept: the round's portfolio and turn searches, in the order of
:func:`jaxpose.search.loop.run_searches`.  Each answer is scored against the truth
(symmetric PCP) and stored with its cost and capsules.  Then adaptive policies are
scored without another fit: "a second round only when round 1's answers disagree",
for a signal computed from round 1 alone and a range of thresholds, each policy's
mean PCP beside the share of images that ran the second round (its time).

    python experiments/restart_signal.py --sets uniform mixed --images 8 --set generations=150
    python experiments/restart_signal.py --sets humanoid --images 8 --set generations=150

``humanoid`` is the natural reference data set (``make_data.py --models humanoid``);
the other names are ``hard_poses.py``'s sets (``--draw tuning`` or ``reference``).
Records go to ``--out`` (one JSON per run, extended image by image: a rerun skips
the images already there).  docs/experiments.md, "An adaptive second restart".
"""

from __future__ import annotations

import argparse
import json
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import common  # noqa: E402
import hard_poses as HP  # noqa: E402
from outputs import write_json  # noqa: E402

import jax  # noqa: E402

import jax.numpy as jnp  # noqa: E402

from jaxpose.kinematics import Links  # noqa: E402
from jaxpose.metrics import evaluate  # noqa: E402
from jaxpose.objective import cloud_spread  # noqa: E402
from jaxpose.search.compiled import Fitter  # noqa: E402
from jaxpose.search.loop import answers_apart, run_searches  # noqa: E402

OUT_DIR = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results", "restart_signal")


def dataset(name: str, draw: str, data_dir: str):
    """``data_dir``: the folder holding ``humanoid/`` and ``hard_poses/``."""
    if name == "humanoid":
        return common.load_dataset("humanoid", data_dir)
    return HP.load_set(name, draw, os.path.join(data_dir, "hard_poses"))


def fit_searches(ds, entry: dict, config, seed: int) -> dict:
    """Every search's answer of one image's fit, scored against the truth."""
    img = common.load_image(ds, entry)
    fitter = Fitter(ds.skeleton, config)
    answers = run_searches(ds.skeleton, fitter.config, fitter.params, jax.random.key(seed),
                           lambda k, p: fitter._search(img.cloud, k, p, None, None)[0])
    out = []
    for res in answers:
        s, e = np.asarray(res.links.start, np.float64), np.asarray(res.links.end, np.float64)
        ev = evaluate(s, e, img.truth["start"], img.truth["end"], ds.skeleton)["symmetric"]
        out.append({"cost": float(res.cost), "pcp": ev["pcp"], "mpjpe_mm": ev["mpjpe_mm"],
                    "start": s.tolist(), "end": e.tolist()})
    return {"set": ds.model, "image": entry["name"], "seed": seed, "searches": out,
            "round_searches": fitter.config.round_searches, "spread": float(cloud_spread(img.cloud))}


def by_cost(searches: list[dict]) -> list[dict]:
    """The answers cheapest first (a non-finite cost last), as the fit ranks them."""
    return sorted(searches, key=lambda s: s["cost"] if np.isfinite(s["cost"]) else np.inf)


def cheapest(searches: list[dict]) -> dict:
    return by_cost(searches)[0]


def disagreement_mm(skel, a: dict, b: dict) -> float:
    """Symmetric MPJPE between two answers (a left/right swap counts as agreement)."""
    return evaluate(a["start"], a["end"], b["start"], b["end"], skel)["symmetric"]["mpjpe_mm"]


def signals(skel, rec: dict) -> dict:
    """Round 1's signals: how far its cheapest answer lies from its runner-up (the next
    cheapest), as symmetric MPJPE (``runner_up_mm``, the metric's optimal matching) and as
    the search's own measure (``apart``: :func:`jaxpose.search.loop.answers_apart` over the
    cloud's spread, what ``restart_apart`` is compared with), and the runner-up's cost gap."""
    r = rec["round_searches"]
    best, runner = by_cost(rec["searches"][:r])[:2]
    links = lambda s: Links(None, None, jnp.asarray(s["start"]), jnp.asarray(s["end"]), None)  # noqa: E731
    return {"runner_up_mm": disagreement_mm(skel, best, runner),
            "apart": float(answers_apart(skel, links(best), links(runner))) / rec["spread"],
            "runner_up_gap": (runner["cost"] - best["cost"]) / best["cost"]}


def policy_table(records: list[dict], sig: list[dict], signal: str, thresholds) -> list[dict]:
    """Per threshold: mean PCP of "round 2 only when the signal exceeds it" (the cost gap:
    only when it is below it, a close runner-up), and how often it ran."""
    rows = []
    for t in thresholds:
        pcps, ran = [], 0
        for rec, s in zip(records, sig):
            r = rec["round_searches"]
            v = s[signal]
            second = v < t if signal == "runner_up_gap" else v > t
            ran += second
            pcps.append(cheapest(rec["searches"] if second else rec["searches"][:r])["pcp"])
        rows.append({"threshold": t, "pcp": float(np.mean(pcps)), "second_round": ran / len(records)})
    return rows


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--sets", nargs="+", default=["uniform", "mixed"])
    p.add_argument("--draw", default="tuning", choices=["tuning", "reference"])
    p.add_argument("--images", type=int, default=8, help="first N images of each set (humanoid: N spread)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE", help="a FitConfig setting")
    p.add_argument("--data", default=common.DATA_DIR, help="data folder (default data/)")
    p.add_argument("--out", default=OUT_DIR)
    args = p.parse_args(argv)

    settings = HP.parse_settings(args.set) | {"restarts": 2}
    config = HP.config_with(settings)
    tag = "-".join(f"{k}={v}" for k, v in sorted(settings.items()))
    os.makedirs(args.out, exist_ok=True)
    draw = args.draw if set(args.sets) - {"humanoid"} else "natural"  # the natural set has no draws
    path = os.path.join(args.out, f"{draw}-{'+'.join(args.sets)}-{tag}.json")
    records = json.load(open(path)) if os.path.exists(path) else []
    done = {(r["set"], r["image"]) for r in records}
    skels = {}
    for name in args.sets:
        ds = dataset(name, args.draw, args.data)
        skels[ds.model] = ds.skeleton
        entries = common.spread(ds.entries, args.images) if name == "humanoid" else ds.entries[:args.images]
        for entry in entries:
            if (ds.model, entry["name"]) in done:
                continue
            rec = fit_searches(ds, entry, config.for_skeleton(ds.skeleton), args.seed)
            records.append(rec)
            write_json(path, records)  # after every image: a rerun skips what is written
            print(f"{rec['set']} {rec['image']}: " + " ".join(f"{s['pcp']:.2f}/{s['cost']:.4f}"
                                                               for s in rec["searches"]), flush=True)
    records = [r for r in records if r["set"] in skels]
    for rec in records:  # records written before the spread was stored
        if "spread" not in rec:
            ds = dataset(rec["set"].split("-")[0], args.draw, args.data)
            entry = next(e for e in ds.entries if e["name"] == rec["image"])
            rec["spread"] = float(cloud_spread(common.load_image(ds, entry).cloud))
    r1 = np.mean([cheapest(r["searches"][:r["round_searches"]])["pcp"] for r in records])
    r2 = np.mean([cheapest(r["searches"])["pcp"] for r in records])
    print(f"{len(records)} images: round 1 {r1:.1%}, both rounds {r2:.1%}")
    sig = [signals(skels[rec["set"]], rec) for rec in records]
    for rec, s in zip(records, sig):
        a = cheapest(rec["searches"][:rec["round_searches"]])["pcp"]
        b = cheapest(rec["searches"])["pcp"]
        print(f"  {rec['set']:>18} {rec['image']:<16} runner-up {s['runner_up_mm']:4.0f} mm, apart "
              f"{s['apart']:.3f} of the spread ({rec['spread']:.2f} m), gap {s['runner_up_gap']:+.3f}: "
              f"pcp {a:.2f} -> {b:.2f}")
    for signal, ts in (("runner_up_mm", (0, 50, 75, 100, 125, 150, 200, 1e9)),
                       ("apart", (0, 0.1, 0.15, 0.2, 0.25, 0.3, 0.4, 1e9)),
                       ("runner_up_gap", (-1, 0.02, 0.05, 0.1, 0.2, 1e9))):
        print(signal)
        for row in policy_table(records, sig, signal, ts):
            op = "<" if signal == "runner_up_gap" else ">"
            print(f"  {op} {row['threshold']:>6g}: pcp {row['pcp']:.1%}, second round on {row['second_round']:.0%}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
