"""The experiments' fits as sharded batches (:func:`jaxpose.fit_batch`): every device of
every process, for ``paper_table.py`` and ``sweep_population.py``.

The fits of one configuration (its images x seeds) share one compiled program; those
not yet in the run store are split among the processes (every ``P``-th), fitted in
batches of ``--batch`` images per device, and stored as :meth:`common.FitRunner.run`
stores them, so a rerun skips them and a run interrupted on one host resumes.  With
several processes the store must be a folder every host sees (a shared file system):
after a configuration, every process reads the others' records from it.

A record's ``wall_seconds`` is its batch's wall time over the batch's images (the
throughput, compilation included in the first batch of a configuration);
``epoch_times`` is empty (a batch reports no progress), so the sweep's
fixed-wall-time mode, which reads per-fit timings, runs its fits one by one.
"""

from __future__ import annotations

import time

import common as C
import jax
import numpy as np
from outputs import log

from jaxpose import distributed
from jaxpose.metrics import evaluate
from jaxpose.objective import Cloud
from jaxpose.parallel import device_mesh, fit_batch

DEFAULT_BATCH = 8


def add_arguments(ap) -> None:
    ap.add_argument("--devices", type=int, metavar="N",
                    help="fit in batches sharded over the first N devices of each process (default: every device "
                         "when there are several, or several processes; a lone CPU fits one by one)")
    ap.add_argument("--batch", type=int, metavar="K", help=f"images per device in a batch (default {DEFAULT_BATCH})")


def enabled(args) -> bool:
    """Batches when asked (--devices, --batch) or when there is more than one device or process."""
    if args.batch is not None and args.batch < 1:
        raise SystemExit("--batch must be >= 1")
    return args.devices is not None or args.batch is not None or jax.device_count() > 1


def is_main_process() -> bool:
    """Whether this process writes the experiment's tables and figures (process 0)."""
    return jax.process_index() == 0


class BatchRunner:
    """Runs and stores fits through a :class:`common.FitRunner`'s store, in sharded batches."""

    def __init__(self, runner: C.FitRunner, devices: int | None = None, batch: int | None = None):
        self.runner = runner
        self.mesh = device_mesh(devices)
        self.local = sum(d.process_index == jax.process_index() for d in self.mesh.devices.flat)
        self.batch = batch or DEFAULT_BATCH
        log(f"batches of {self.batch} images per device on {self.mesh.devices.size} "
            f"{self.mesh.devices.flat[0].platform.upper()} device(s), {jax.process_count()} process(es)")

    def run(self, ds: C.Dataset, entries: list[dict], label: str, config, seeds: list[int],
            extra: dict | None = None) -> list[dict]:
        """The records of every ``(seed, entry)`` fit of ``config``, seed-major (the
        order of FitRunner loops), from the store or fitted now."""
        config = config.for_skeleton(ds.skeleton)
        jobs = [(seed, entry) for seed in seeds for entry in entries]
        keys = [self.runner.keys(ds, entry["name"], label, config, seed)[0] for seed, entry in jobs]
        pending = [(job, key) for job, key in zip(jobs, keys) if self.runner.store.get(key) is None]
        self.runner.done += len(jobs)
        self.runner.skipped += len(jobs) - len(pending)
        mine = distributed.share(pending)
        size = self.batch * self.local
        largest = len(mine)
        if jax.process_count() > 1:
            from jax.experimental import multihost_utils

            largest = int(np.max(multihost_utils.process_allgather(np.int32(len(mine)))))
        for b in range(-(-largest // size)):
            part = mine[b * size:(b + 1) * size]
            images = [C.load_image(ds, entry) for (_, entry), _ in part]
            n = C.InputOptions.max_points
            clouds = Cloud(np.stack([i.cloud.points for i in images]) if images else np.zeros((0, n, 3), np.float32),
                           np.stack([i.cloud.weights for i in images]) if images else np.zeros((0, n), np.float32))
            rngs = (jax.numpy.stack([jax.random.key(seed) for (seed, _), _ in part]) if part
                    else jax.random.split(jax.random.key(0), 0))  # a process with nothing left
            t0 = time.perf_counter()
            res = fit_batch(clouds, ds.skeleton, rngs, config, self.mesh)
            seconds = time.perf_counter() - t0
            for i, (((seed, _), key), img) in enumerate(zip(part, images)):
                one = jax.tree_util.tree_map(lambda x: x[i], res)  # noqa: B023 - used at once
                rec = self._record(ds, img, config, seed, one, seconds, len(part), int(self.mesh.devices.size))
                rec.update({"label": label, "key": key, "fingerprint": C.run_fingerprint(ds, config),
                            "planned_evaluations": C.planned_evaluations(config, skel=ds.skeleton), **(extra or {})})
                self.runner._check_counts(rec, config, label, ds.skeleton)
                self.runner.store.put(key, rec)
                self.runner.ran += 1
            if part:
                log(f"[{self.runner.done:>4}/{self.runner.total}] {ds.model:<8} {label:<20} batch {b + 1}: "
                    f"{len(part)} fits in {seconds:.1f} s")
        distributed.barrier(f"{ds.model}/{label}/{config.generations}")
        records = [self.runner.store.get(key) for key in keys]
        missing = [k for k, r in zip(keys, records) if r is None]
        if missing:
            raise SystemExit(f"{len(missing)} fits are not in the run store (is it a folder every host sees?): "
                             f"{missing[0]}")
        return records

    @staticmethod
    def _record(ds, img, config, seed, res, seconds, images, devices) -> dict:
        """The record :func:`common.fit_image` makes, from one fit of a batch."""
        start, end = np.asarray(res.links.start, np.float64), np.asarray(res.links.end, np.float64)
        ev = evaluate(start, end, img.truth["start"], img.truth["end"], ds.skeleton)
        return {
            "model": ds.model, "image": img.name, "seed": int(seed), "algorithm": config.algorithm,
            "population": config.population, "generations": config.generations,
            "symmetric": ev["symmetric"], "strict": ev["strict"], "cost": float(res.cost),
            "objective_evaluations": int(res.objective_evaluations),
            "gradient_evaluations": int(res.gradient_evaluations),
            "distance_evaluations": float(res.distance_evaluations),
            "wall_seconds": seconds / images, "call_seconds": seconds / images, "epoch_times": [],
            "batch": {"seconds": seconds, "images": images, "devices": devices,
                      "processes": jax.process_count()},
            "links": {"names": list(ds.skeleton.link_names), "start": start.tolist(), "end": end.tolist()},
            "meta": {k: v for k, v in img.entry.items() if k not in ("image", "background", "truth")},
            "machine": C.machine_id(), "finished": C.now_iso(),
        }
