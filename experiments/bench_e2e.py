"""End-to-end fits for the benchmark (``bench.py``): rendered spider / humanoid images
fitted with the public search (:class:`jaxpose.search.Fitter`), compile time apart from
run time, objective evaluations per second, and link accuracy (symmetric PCP) after
every epoch, so that the time to reach an accuracy can be read.
"""

from __future__ import annotations

import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np
from bench_kernel import get_skeleton
from bench_timing import CompileWatch
from outputs import log

from jaxpose.search import Fitter, best_of, evaluation_counts

E2E_PRESETS = {
    # the shipped defaults (FitConfig(): islands, memetic and final refinement)
    "default": dict(),
    # small and without gradient refinement: compiles in a fraction of the time
    "quick": dict(population=128, generations=40, epoch=10, memetic_steps=0, final_refine_steps=0),
}


def fit_traced(skel, config, cloud, key):
    """One fit, stepped epoch by epoch as :meth:`jaxpose.search.Fitter.run` steps it, with the
    elapsed time, evaluations and best genome after every epoch: ``(result, wall seconds,
    snapshots)``."""
    fitter = Fitter(skel, config)
    t0 = time.perf_counter()
    st = fitter.init(cloud, key)  # compiles the fit's programs when this signature is cold
    hists, gen, snaps = [], 0, []
    for length in fitter.epoch_lengths:
        st, h = fitter.step(st, length)
        hists.append(h)
        gen += length
        best = float(h[-1])  # synchronises, as Fitter's progress report does
        snaps.append(dict(generation=gen, elapsed_s=time.perf_counter() - t0, best_cost=best, state=st))
    res = jax.block_until_ready(fitter.finish(st, jnp.concatenate(hists)))
    wall = time.perf_counter() - t0
    for s in snaps:  # read out after the clock stopped
        st = s.pop("state")
        s["evaluations"] = int(sum(int(n) for n in evaluation_counts(st)))
        s["genome"] = best_of(st)[0]
        s["bounds"] = st.bounds  # shared by all islands
    return res, wall, snaps


def _links_of(skel):
    from jaxpose.genome import decode
    from jaxpose.kinematics import forward_kinematics

    @jax.jit
    def links(bounds, genome):
        lk = forward_kinematics(skel, decode(skel, bounds, genome))
        return lk.start, lk.end

    return links


def run_e2e(name: str, args) -> dict:
    from jaxpose.camera import depth_to_cloud
    from jaxpose.datasets import random_pose, render_orbit
    from jaxpose.metrics import evaluate
    from jaxpose.search import FitConfig

    skel = get_skeleton(name)
    config = FitConfig(**E2E_PRESETS[args.e2e_preset]).for_skeleton(skel)  # generations resolved
    t = time.perf_counter()
    views, clouds = [], []
    for i in range(args.e2e_images):
        pose = random_pose(skel, np.random.default_rng([args.seed, i]))
        view = render_orbit(skel, pose, elevation_deg=20.0, azimuth_deg=40.0 * i, seed=args.seed + i)
        views.append(view)
        clouds.append(depth_to_cloud(view.depth, view.intrinsics, max_points=args.e2e_points, seed=i))
    render_s = time.perf_counter() - t
    links_of = _links_of(skel)

    def accuracy(view, start, end) -> dict:
        ev = evaluate(np.asarray(start), np.asarray(end), view.start, view.end, skel)
        return {"pcp_symmetric": ev["symmetric"]["pcp"], "pcp_strict": ev["strict"]["pcp"],
                "mpjpe_mm_symmetric": ev["symmetric"]["mpjpe_mm"]}

    runs = []
    for i, (view, cloud) in enumerate(zip(views, clouds)):
        with CompileWatch() as cw:
            res, wall, snaps = fit_traced(skel, config, cloud, jax.random.key(args.seed + i))
        evals = int(res.objective_evaluations) + int(res.gradient_evaluations)
        traj = []
        for s in snaps:
            acc = accuracy(view, *links_of(s["bounds"], s["genome"]))
            traj.append({k: s[k] for k in ("generation", "elapsed_s", "evaluations", "best_cost")} | acc)
        final = accuracy(view, res.links.start, res.links.end)
        traj.append({"generation": config.generations, "elapsed_s": wall, "evaluations": evals,
                     "best_cost": float(res.cost), "final": True} | final)
        runs.append({
            "image": i, "cold": i == 0, "wall_s": wall, "compile_s": cw.seconds, "compiles": len(cw.compiles),
            "compiled": sorted(set(cw.compiles)), "objective_evaluations": int(res.objective_evaluations),
            "gradient_evaluations": int(res.gradient_evaluations),
            "distance_evaluations": float(res.distance_evaluations), "cost": float(res.cost),
            "points_used": int(np.sum(np.asarray(cloud.weights) > 0)), **final, "trajectory": traj,
        })
        log(f"    {name} image {i} ({'cold' if i == 0 else 'warm'}): {wall:.2f} s "
            f"(compile {cw.seconds:.1f} s, {len(cw.compiles)} executables), {evals} evaluations, "
            f"cost {float(res.cost):.4f}, symmetric PCP {final['pcp_symmetric']:.3f}")
    warm = [r for r in runs if not r["cold"]] or runs
    run_s = statistics.median(r["wall_s"] - (r["compile_s"] if r["cold"] else 0.0) for r in warm)
    evals = statistics.median(r["objective_evaluations"] + r["gradient_evaluations"] for r in warm)
    dists = statistics.median(r["distance_evaluations"] for r in warm)
    thresholds = {}
    for thr in args.e2e_pcp:
        reached = []
        for r in warm:  # the first snapshot from which the accuracy stays at or above thr to the end
            hit = None
            for p in r["trajectory"][::-1]:
                if p.get("pcp_symmetric", -1) < thr - 1e-9:
                    break
                hit = p["elapsed_s"]
            reached.append(hit)
        got = [x for x in reached if x is not None]
        thresholds[f"{thr:g}"] = {"reached": len(got), "of": len(reached),
                                  "median_s": statistics.median(got) if got else None}
    return {
        "skeleton": name, "L": skel.num_links, "max_points": args.e2e_points, "preset": args.e2e_preset,
        "config": {k: v for k, v in config.to_dict().items() if k != "objective"},
        "render_s": render_s,
        "compile_s": runs[0]["compile_s"],  # trace + lowering + XLA, summed over the compiling threads
        # what a user waits: the cold fit minus a warm one (unknown without a warm fit)
        "compile_wall_s": runs[0]["wall_s"] - run_s if len(runs) > 1 else None,
        "cold_wall_s": runs[0]["wall_s"],
        "warm_run_s": run_s,
        "evaluations": evals,
        "evals_per_s": evals / run_s,
        "distance_evals_per_s": dists / run_s,
        "recompiles_warm": sum(r["compiles"] for r in runs if not r["cold"]),
        "pcp_symmetric_mean": float(np.mean([r["pcp_symmetric"] for r in runs])),
        "pcp_symmetric": [r["pcp_symmetric"] for r in runs],
        "time_to_pcp": thresholds,
        "runs": runs,
        "done": True,
    }
