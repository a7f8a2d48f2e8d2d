"""Run in a subprocess by tests/parallel/: fit a few probe clouds with
:func:`jaxpose.parallel.fit_batch` and save the results (``.npz``).

``XLA_FLAGS`` (forced host devices) must be set by the caller: XLA reads it once,
when JAX starts.  Usage::

    batch_worker.py OUT.npz --mesh 1 2 [--images 0 2] [--refine]

With ``JAXPOSE_DISTRIBUTED=1`` and ``JAX_COORDINATOR_ADDRESS``, ``JAX_NUM_PROCESSES``,
``JAX_PROCESS_ID`` in the environment, the process joins a run when jaxpose is imported.

Each ``--mesh n`` fits the images on the first ``n`` devices of every process;
the file holds ``cost_n``, ``genome_n``, ``ends_n`` and the unsharded ``fit`` of
the images one by one (``single_*``) with ``--single``.
"""

from __future__ import annotations

import argparse
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path[:0] = [os.path.dirname(HERE), os.path.join(os.path.dirname(HERE), "search")]

import jaxpose  # noqa: E402,F401 - before JAX computes anything
from jaxpose import distributed  # noqa: E402

IMAGES = 3  # probe clouds 0..2 with 60, 70, 80 valid points


def config(refine: bool):
    import dataclasses

    from search_cases import OBJ

    from jaxpose.search import FitConfig

    # no limb sweep: on a search this short it does most of the work, and a GA from fresh draws turns the
    # round-off between programs compiled for 1 and N devices into different answers (docs/scaling.md)
    cfg = FitConfig(population=8, generations=4, epoch=2, memetic_top=2, memetic_steps=2, final_refine_top=2,
                    final_refine_steps=2, islands=2, objective=OBJ, limb_sweep=0, pivot_sweep=0, turns=0)
    return cfg if refine else dataclasses.replace(cfg, memetic_steps=0, final_refine_steps=0)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("out")
    ap.add_argument("--mesh", type=int, nargs="+", default=[1])
    ap.add_argument("--images", type=int, nargs="+", default=list(range(IMAGES)))
    ap.add_argument("--refine", action="store_true")
    ap.add_argument("--single", action="store_true")
    ap.add_argument("--track", action="store_true", help="also 3 sequences of 3 frames tracked on 1 and 2 devices")
    ap.add_argument("--islands", action="store_true", help="also the first image with its islands split over 2 devices")
    args = ap.parse_args(argv)
    distributed.check()

    import jax
    import numpy as np
    from search_cases import probe_cloud, probe_skeleton

    from jaxpose.parallel import device_mesh, fit_batch

    skel, cfg = probe_skeleton(), config(args.refine)
    clouds = [probe_cloud(i, 60 + 10 * i) for i in args.images]
    batch = jax.tree_util.tree_map(lambda *x: np.stack(x), *clouds)
    keys = jax.random.split(jax.random.key(0), IMAGES)[np.asarray(args.images, int)]
    out = {"devices": len(jax.devices()), "processes": jax.process_count()}
    for n in args.mesh:
        r = fit_batch(batch, skel, keys, cfg, device_mesh(n))
        out.update({f"cost_{n}": r.cost, f"genome_{n}": r.genome, f"ends_{n}": r.links.end,
                    f"evals_{n}": r.objective_evaluations})
    if args.single:
        fit = jax.jit(jaxpose.fit, static_argnames="config")
        rs = [fit(c, skel, k, cfg) for c, k in zip(clouds, keys)]
        out.update({"single_cost": np.stack([r.cost for r in rs]), "single_genome": np.stack([r.genome for r in rs]),
                    "single_ends": np.stack([r.links.end for r in rs])})
    if args.track:
        import dataclasses

        from jaxpose.parallel import track_batch
        from jaxpose.tracking import TrackConfig, track

        tcfg = TrackConfig(fit=dataclasses.replace(cfg, generations=2), population=8, generations=2, refine_steps=2)
        seqs = [[probe_cloud(10 * s + t, 60 + 5 * t) for t in range(3)] for s in range(3)]
        stack = jax.tree_util.tree_map(lambda *x: np.stack(x), *[jax.tree_util.tree_map(lambda *y: np.stack(y), *q)
                                                                 for q in seqs])
        for n in (1, 2):
            fr = track_batch(stack, skel, keys, tcfg, device_mesh(n))
            out.update({f"track_cost_{n}": fr.result.cost, f"track_mode_{n}": fr.mode,
                        f"track_ends_{n}": fr.result.links.end})
        one = jax.jit(track, static_argnames="config")(jax.tree_util.tree_map(lambda x: x[1], stack), skel, keys[1],
                                                       tcfg)
        out.update({"track_single_cost": one.result.cost, "track_single_mode": one.mode,
                    "track_single_ends": one.result.links.end})
    if args.islands:
        import re

        from jaxpose.parallel import _island_program, fit_islands

        mesh = device_mesh(2)
        r = fit_islands(clouds[0], skel, keys[0], cfg, mesh)
        out.update({"islands_cost": r.cost, "islands_genome": r.genome, "islands_ends": r.links.end})
        host = lambda tree: jax.tree_util.tree_map(np.asarray, tree)  # noqa: E731
        hlo = _island_program(cfg.for_skeleton(skel), mesh).lower(
            clouds[0], host(skel), keys[0], host(cfg.params())).compile().as_text()
        out["islands_exchanges"] = len(re.findall(r"(?:all-gather|all-to-all|collective-permute)\(", hlo))
        out["islands_local_shapes"] = len(re.findall(rf"\[1,{cfg.population},", hlo))
    np.savez(args.out, **out)
    distributed.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
