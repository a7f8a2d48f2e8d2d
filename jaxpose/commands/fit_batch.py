"""``jaxpose fit`` on several inputs, or on several processes: batches sharded over
the devices (:func:`jaxpose.parallel.fit_batch`), results written after each batch.

Each process takes its share of the inputs (every ``P``-th, :func:`jaxpose.distributed.share`),
skips those already written with ``--resume``, reads and checks the rest, then fits
them in batches of ``--batch`` images per device; every process runs as many batches
(the largest share decides; a process with fewer inputs pads with copies) because
every batch is one program over all processes' devices.
"""

from __future__ import annotations

import os
import time
import warnings

import jax
import numpy as np

from ..errors import ConfigError


def agree(ok: bool, what: str) -> None:
    """Every process learns whether every process succeeded at ``what`` (so that all
    stop together instead of waiting for the others' next program)."""
    if jax.process_count() == 1:
        return
    from jax.experimental import multihost_utils

    flags = np.asarray(multihost_utils.process_allgather(np.int32(ok)))
    if ok and not flags.all():
        bad = ", ".join(str(i) for i in np.flatnonzero(flags == 0))
        raise ConfigError(f"{what} failed on process {bad} (its error is in its own output)")


def largest(n: int) -> int:
    if jax.process_count() == 1:
        return n
    from jax.experimental import multihost_utils

    return int(np.max(multihost_utils.process_allgather(np.int32(n))))


def _observe(path, skel, options):
    """``(depth or view, intrinsics, cloud, input record, warnings)`` of one input, as
    :func:`jaxpose.fit_file` reads it."""
    from ..io.cloud_file import is_cloud_file
    from ..pipeline import _depth_record, load_cloud_observation, read_observation, scale_warning, unused_depth_scale

    if is_cloud_file(path):
        depth, k, cloud, record = load_cloud_observation(path, options)
        unused = None
    else:
        depth, k, cloud, scaled = read_observation(path, options)
        record, unused = _depth_record(path, options, k, cloud, scaled), unused_depth_scale(options, scaled, path)
    notes = [w for w in (scale_warning(skel, cloud, str(path)), unused) if w]
    return depth, k, cloud, record, notes


def run_batches(args, jobs, skel, skel_file, config, per_input) -> int:
    from .. import distributed
    from ..io.atomic import write_json
    from ..io.cloud_file import is_cloud_file
    from ..io.fit_result import result_document
    from ..objective import Cloud
    from ..parallel import device_mesh, fit_batch
    from ..pipeline import check_input
    from .fit import _show_input_warning, finished
    from .robot_options import robot_record

    mine = distributed.share(jobs)
    todo = [job for job in mine if not (args.resume and finished(job))]
    quiet, P = args.quiet, jax.process_count()
    who = f"process {jax.process_index()} of {P}: " if P > 1 else ""
    if not quiet and len(todo) < len(mine):
        print(f"{who}{len(mine) - len(todo)} of {len(mine)} results already written, skipped", flush=True)
    ok = False
    try:
        with warnings.catch_warnings():
            warnings.showwarning = _show_input_warning
            for path, _, _ in todo:  # every input is read and checked before the first search
                check_input(path, per_input[path])
        ok = True
    finally:
        if not ok and P > 1:  # the others learn it before they wait for this process's programs
            agree(False, "reading the inputs")
    agree(True, "reading the inputs")
    mesh = device_mesh(args.devices)
    local = [d for d in mesh.devices.flat if d.process_index == jax.process_index()]
    from .fit import BATCH

    size = (args.batch or BATCH) * len(local)
    batches = -(-largest(len(todo)) // size)
    if not quiet and jax.process_index() == 0:
        print(f"{len(jobs)} inputs on {mesh.devices.size} {local[0].platform.upper()} device(s)"
              f"{f' of {P} processes' if P > 1 else ''}, {size} images per batch and process", flush=True)
    failed = []
    for b in range(batches):
        part = todo[b * size:(b + 1) * size]
        seen = []
        with warnings.catch_warnings():
            warnings.showwarning = _show_input_warning
            for path, _, _ in part:
                seen.append(_observe(path, skel, per_input[path]))
                for w in seen[-1][4]:
                    print(f"jaxpose: warning: {w}", flush=True)
        n = args.max_points  # every input's cloud size (a process with no input left passes none)
        clouds = Cloud(np.stack([o[2].points for o in seen]) if seen else np.zeros((0, n, 3), np.float32),
                       np.stack([o[2].weights for o in seen]) if seen else np.zeros((0, n), np.float32))
        t0 = time.perf_counter()
        res = fit_batch(clouds, skel, jax.random.key(args.seed), config, mesh)
        seconds = time.perf_counter() - t0
        for i, ((path, result, plot), (depth, k, _, record, notes)) in enumerate(zip(part, seen)):
            one = jax.tree_util.tree_map(lambda x: x[i], res)  # noqa: B023 - used at once
            if not (np.isfinite(float(one.cost)) and np.all(np.isfinite(np.asarray(one.links.end)))):
                failed.append(path)
                continue
            one = one._replace(wall_time=np.float32(seconds / len(part)))
            doc = result_document(skel, skel_file, one, config, args.seed, record)
            if is_cloud_file(path):
                doc["frame"] = "sensor (the cloud's viewpoint; x right, y down, z forward), metres"
            doc["skeleton"].update(robot_record(args, skel_file))
            doc["timing"]["batch"] = {"seconds": seconds, "images": len(part), "devices": int(mesh.devices.size),
                                      "processes": P}
            doc["warnings"] = notes
            msg = f"{who}{os.path.basename(path)}: cost {doc['cost']:.5f} -> {result}"
            if plot:  # the plot first: a result file always has its plot beside it
                from ..viz import overlay_figure, save_figure

                fig = overlay_figure(depth, k, doc["links"],
                                     title=f"{skel.name} ({config.algorithm}), cost {doc['cost']:.4f}")
                save_figure(fig, plot)
                msg += f", {plot}"
            write_json(result, doc)
            if not quiet:
                print(msg, flush=True)
        if not quiet and part:
            print(f"{who}batch {b + 1}/{batches}: {len(part)} images in {seconds:.1f} s", flush=True)
    if failed:
        raise ConfigError(f"{failed[0]}: the fit of {skel.name!r} ended with a non-finite cost or pose; check the "
                          f"skeleton's ranges and the depth scale ({len(failed)} input(s) not written)")
    return 0


__all__ = ["agree", "largest", "run_batches"]
