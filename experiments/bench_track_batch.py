"""Several sequences tracked at once against one by one, on this machine, in one run:

- one by one: ``jaxpose.tracking.track`` (one jitted ``lax.scan``) per sequence;
- batched: ``jaxpose.parallel.track_batch`` on one device (``track_batched``: the
  global search runs only on frames where some sequence needs it);
- with ``--vmap``: ``jax.vmap(track)``, where every frame pays for the global search
  (what ``track_batch`` ran before ``track_batched``).

Each row: a cold call (compiles), then ``--repeats`` warm calls; median and range
of their wall times, and the mean per-frame symmetric PCP (the rows should agree).
Writes experiments/results/bench_track_batch.json (or --out).

    .venv/bin/python experiments/bench_track_batch.py --model spider --sequences 4 --frames 20 --vmap
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import statistics
import sys
import time

import jax
import numpy as np
from machine import machine_info
from outputs import log, rel, write_json
from track_table import clouds_of, score

import jaxpose as jp
from jaxpose import sequences as S
from jaxpose.parallel import device_mesh, track_batch
from jaxpose.tracking import TrackConfig, track

OUT = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results", "bench_track_batch.json")


def timed(call, repeats: int):
    """``(cold seconds, warm seconds list, last result)``."""
    t0 = time.perf_counter()
    out = jax.block_until_ready(call())
    cold, times = time.perf_counter() - t0, []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = jax.block_until_ready(call())
        times.append(time.perf_counter() - t0)
    return cold, times, out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default="spider", choices=["spider", "humanoid"])
    ap.add_argument("--sequences", type=int, default=4)
    ap.add_argument("--frames", type=int, default=20)
    ap.add_argument("--seed", type=int, default=2)
    ap.add_argument("--generations", type=int, help="the global search's generations (default: the model's)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--vmap", action="store_true", help="also jax.vmap(track) (slow: a global search every frame)")
    ap.add_argument("--out", default=OUT)
    args = ap.parse_args(argv)
    skel = jp.load_skeleton(args.model)
    make = S.spider_sequence if args.model == "spider" else S.humanoid_sequence
    seqs = [make(skel, seed=args.seed, frames=args.frames, index=i) for i in range(args.sequences)]
    clouds = [clouds_of(s) for s in seqs]
    stacked = jp.Cloud(np.stack([[c.points for c in cs] for cs in clouds]),
                       np.stack([[c.weights for c in cs] for cs in clouds]))
    config = TrackConfig()
    config = dataclasses.replace(config, fit=dataclasses.replace(config.fit, generations=args.generations))
    config = config.validate().for_skeleton(skel)
    keys = jax.random.split(jax.random.key(0), args.sequences)
    one = jax.jit(track, static_argnames="config")
    frames_total = args.sequences * args.frames

    def pcp(frames, i):
        links = frames.result.links
        return float(np.mean([score(skel, jax.tree_util.tree_map(lambda a: np.asarray(a)[t], links), v)[0]
                              for t, v in enumerate(seqs[i].views) if v is not None]))

    def row(name, call, per_sequence):
        cold, times, out = timed(call, args.repeats)
        each = out if per_sequence else [jax.tree_util.tree_map(lambda a: a[i], out) for i in range(args.sequences)]
        acc = [pcp(f, i) for i, f in enumerate(each)]
        med = statistics.median(times)
        r = {"name": name, "cold_seconds": cold, "seconds": times, "median_seconds": med,
             "frames_per_second": frames_total / med, "pcp": acc,
             "modes": [np.asarray(f.mode).tolist() for f in each]}
        log(f"{name:>12}: {frames_total} frames in {med:.2f} s (range {min(times):.2f}-{max(times):.2f}; cold "
            f"{cold:.1f} s): {frames_total / med:.1f} frames/s; PCP per sequence "
            f"{' '.join(f'{a:.3f}' for a in acc)}")
        return r

    rows = [row("one by one", lambda: [one(jax.tree_util.tree_map(lambda a: a[i], stacked), skel, keys[i], config)
                                        for i in range(args.sequences)], True),
            row("batched", lambda: track_batch(stacked, skel, keys, config, device_mesh(1)), False)]
    if args.vmap:
        vm = jax.jit(jax.vmap(track, in_axes=(0, None, 0, None)), static_argnames="config")
        rows.append(row("vmap(track)", lambda: vm(stacked, skel, keys, config), False))
    base = rows[0]["median_seconds"]
    for r in rows:
        r["time_against_one_by_one"] = r["median_seconds"] / base
    log("time against one by one: " + ", ".join(f"{r['name']} {r['time_against_one_by_one']:.2f}" for r in rows))
    write_json(args.out, {"title": "sequences tracked at once against one by one", "machine": machine_info(),
                          "model": args.model, "sequences": args.sequences, "frames": args.frames,
                          "seed": args.seed, "config": config.to_dict(), "rows": rows})
    log(f"wrote {rel(args.out)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
