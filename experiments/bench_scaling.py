"""Images per second of a sharded batch (jaxpose.fit_batch) against the device count,
and of fitting the same images one by one (fit_cloud), on this machine; with
``--split-one``, also the time of one fit whose islands are split over the devices
(jaxpose.parallel.fit_islands, what ``jaxpose fit INPUT --devices N`` runs).

Devices are whatever JAX sees.  On a CPU, force host devices before JAX starts::

    XLA_FLAGS=--xla_force_host_platform_device_count=4 python experiments/bench_scaling.py

Forced host devices share the same cores, so on a CPU this measures the overhead
of sharding, not a speed-up.  Each row: a warm-up batch (compiles), then
``--repeats`` timed batches; the median and range of their wall times.
Writes experiments/results/bench_scaling.json (or --out).
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time

import common as C
import jax
import numpy as np
from machine import machine_info
from outputs import log, rel, write_json

from jaxpose.metrics import evaluate
from jaxpose.objective import Cloud
from jaxpose.parallel import device_mesh, fit_batch, fit_islands
from jaxpose.search import FitConfig, fit_cloud


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--model", default="spider", choices=C.MODELS)
    ap.add_argument("--images", type=int, default=8, help="images per batch (default 8)")
    ap.add_argument("--devices", type=int, nargs="+", help="device counts (default 1, 2, 4, ... up to all)")
    ap.add_argument("--generations", type=int, help="FitConfig.generations (default: the model's automatic count)")
    ap.add_argument("--islands", type=int, default=FitConfig.islands)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--one-by-one", action="store_true", help="also fit the images one by one (fit_cloud)")
    ap.add_argument("--split-one", action="store_true",
                    help="also one fit (the first image) with its islands split over each device count")
    ap.add_argument("--out", default=os.path.join(C.RESULTS_DIR, "bench_scaling.json"))
    args = ap.parse_args(argv)
    C.ensure_data([args.model])
    ds = C.load_dataset(args.model)
    entries = C.spread(ds.entries, args.images) if len(ds.entries) >= args.images else ds.entries
    images = [C.load_image(ds, e) for e in entries]
    while len(images) < args.images:  # a small data set: repeat its images
        images.append(images[len(images) % len(entries)])
    clouds = Cloud(np.stack([i.cloud.points for i in images]), np.stack([i.cloud.weights for i in images]))
    keys = jax.random.split(jax.random.key(0), len(images))
    config = FitConfig(generations=args.generations, islands=args.islands).for_skeleton(ds.skeleton)
    counts = args.devices or [n for n in (1, 2, 4, 8, 16, 32, 64) if n <= jax.local_device_count()]
    rows = []
    for n in counts:
        mesh = device_mesh(n)
        t0 = time.perf_counter()
        first = fit_batch(clouds, ds.skeleton, keys, config, mesh)
        cold = time.perf_counter() - t0
        times = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            res = fit_batch(clouds, ds.skeleton, keys, config, mesh)
            times.append(time.perf_counter() - t0)
        assert np.array_equal(np.asarray(res.cost), np.asarray(first.cost))  # warm runs repeat the cold one
        med = statistics.median(times)
        pcp = [evaluate(np.asarray(res.links.start[i], np.float64), np.asarray(res.links.end[i], np.float64),
                        img.truth["start"], img.truth["end"], ds.skeleton)["symmetric"]["pcp"]
               for i, img in enumerate(images)]
        rows.append({"devices": n, "images": len(images), "cold_seconds": cold, "seconds": times,
                     "median_seconds": med, "images_per_second": len(images) / med,
                     "costs": np.asarray(res.cost).tolist(), "link_accuracy": pcp,
                     "mean_cost": float(np.mean(res.cost))})
        log(f"{n:>3} device(s): {len(images)} images in {med:.2f} s (range {min(times):.2f}-{max(times):.2f}; "
            f"cold {cold:.1f} s): {len(images) / med:.2f} images/s; link accuracy {np.mean(pcp):.3f}, "
            f"costs {' '.join(f'{c:.5f}' for c in rows[-1]['costs'])}")
    split = [split_one(images[0], ds.skeleton, config, n, args.repeats) for n in counts] if args.split_one else None
    single = None
    if args.one_by_one:
        fit_cloud(images[0].cloud, ds.skeleton, 0, config)  # compiles
        times = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            for img in images:
                fit_cloud(img.cloud, ds.skeleton, 0, config)
            times.append(time.perf_counter() - t0)
        med = statistics.median(times)
        single = {"images": len(images), "seconds": times, "median_seconds": med,
                  "images_per_second": len(images) / med}
        log(f"one by one (fit_cloud): {len(images)} images in {med:.2f} s (range {min(times):.2f}-{max(times):.2f}): "
            f"{len(images) / med:.2f} images/s")
    write_json(args.out, {
        "title": "images/s of a sharded batch against devices", "machine": machine_info(),
        "platform": jax.devices()[0].platform, "local_devices": jax.local_device_count(),
        "xla_flags": os.environ.get("XLA_FLAGS", ""), "model": args.model, "config": config.to_dict(),
        "rows": rows, "one_by_one": single, "split_one": split,
    })
    log(f"wrote {rel(args.out)}")
    return 0


def split_one(image, skel, config, n: int, repeats: int) -> dict:
    """One fit of ``image`` with its islands split over ``n`` devices: cold (compiles), then ``repeats`` warm."""
    mesh, key = device_mesh(n), jax.random.key(0)
    t0 = time.perf_counter()
    jax.block_until_ready(fit_islands(image.cloud, skel, key, config, mesh))
    cold, times = time.perf_counter() - t0, []
    for _ in range(repeats):
        t0 = time.perf_counter()
        res = jax.block_until_ready(fit_islands(image.cloud, skel, key, config, mesh))
        times.append(time.perf_counter() - t0)
    pcp = evaluate(np.asarray(res.links.start, np.float64), np.asarray(res.links.end, np.float64),
                   image.truth["start"], image.truth["end"], skel)["symmetric"]["pcp"]
    med = statistics.median(times)
    log(f"one fit, islands over {n} device(s): {med:.2f} s (range {min(times):.2f}-{max(times):.2f}; cold "
        f"{cold:.1f} s), cost {float(res.cost):.5f}, link accuracy {pcp:.3f}")
    return {"devices": n, "cold_seconds": cold, "seconds": times, "median_seconds": med,
            "cost": float(res.cost), "link_accuracy": pcp}


if __name__ == "__main__":
    sys.exit(main())
