"""A tracked frame: a small GA around the motion model's prediction, then Adam, then
(optional, ``TrackConfig.sweep_limbs``) a sweep of a few limbs in turn (docs/tracking.md,
"One frame").

The local search works on its own genome bounds, centred on the prediction: the
root may move ``TrackConfig.move`` (times the scale) and turn ``TrackConfig.turn``
radians about each axis, the scale stays within ``scale_window`` of the last one,
joints and lengths keep the skeleton's ranges.  The root's orientation genes are a
turn *relative to the predicted orientation* (composed as rotation matrices), so
a subject that faces any way is tracked without the roll-pitch-yaw seams of the
global genome.  The GA and the refinement are the search's own
(:class:`~jaxpose.search.BranchSwapGA`, :func:`~jaxpose.search.refine`).
"""

from __future__ import annotations

import dataclasses
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..genome import Bounds, decode, encode, genome_bounds, genome_layout, held_bounds, window
from ..kinematics import Links, forward_kinematics
from ..objective import Cloud, Observation, observe
from ..search.config import FitConfig
from ..search.cost import pose_cost
from ..search.genes import tie_lengths
from ..search.loop import make_algorithm, start_algorithm
from ..search.memetic import keep_better
from ..search.refine import refine
from ..search.sweep import hold, sweep_masks, sweep_rows
from ..skeleton import Pose, Skeleton
from .config import TrackConfig

SCALE = 6


class LocalFit(NamedTuple):
    pose: Pose
    genome: jax.Array  # (D,) in the local bounds
    links: Links
    cost: jax.Array
    history: jax.Array  # (generations,)


def local_bounds(skel: Skeleton, config: TrackConfig, pred: Pose) -> Bounds:
    """Gene ranges around the prediction ``pred`` (the root's angles: a turn relative to
    its orientation, :func:`~jaxpose.genome.held_bounds`; the scale within ``scale_window``
    of the prediction's or the known ``fit.scale``, the lengths within ``length_window`` of the
    prediction's when it is set)."""
    b = genome_bounds(skel, pred.root_t, config.move * pred.scale)
    b = held_bounds(b, pred.root_rpy, config.turn, jnp.asarray(True))
    lo, hi = b.lo, b.hi
    windows = [(np.asarray([SCALE], np.int32), pred.scale[None], skel.scale_lo[None], skel.scale_hi[None],
                config.scale_window)]
    genes, links = genome_layout(skel).length_genes()
    if config.length_window and genes.size:  # bones do not change length from frame to frame
        windows.append((genes, pred.lengths[links], skel.length_lo[links], skel.length_hi[links],
                        config.length_window))
    for idx, value, v_lo, v_hi, w in windows:
        w_lo, w_hi = window(value, v_lo, v_hi, w)
        lo, hi = lo.at[idx].set(w_lo), hi.at[idx].set(w_hi)
    if config.fit.scale is not None:  # known: held, as in the global search
        lo, hi = lo.at[SCALE].set(config.fit.scale), hi.at[SCALE].set(config.fit.scale)
    return b._replace(lo=lo, hi=hi)


def local_cost_fn(skel: Skeleton, fit: FitConfig, obs: Observation, bounds: Bounds):
    """``cost(genomes (P, D)) -> (P,)``: the global search's objective on local genomes."""
    params = fit.params()

    def cost(genomes):
        if fit.tie_lengths:
            genomes = tie_lengths(skel, genomes)
        poses = jax.vmap(partial(decode, skel, bounds))(genomes)
        c = pose_cost(skel, obs, poses, fit.objective, params)
        return jnp.where(jnp.isfinite(c), c, jnp.inf)

    return cost


def local_fit(skel: Skeleton, config: TrackConfig, cloud: Cloud, pred: Pose, last: Pose, key,
              frame=0) -> LocalFit:
    """Search around the prediction ``pred`` (``last``: the last frame's pose, also in
    the first population), refine the best, then sweep ``config.sweep_limbs`` limbs (the
    ``frame``-th in turn).  ``config.fit`` must be resolved."""
    fit = config.fit
    obs = observe(cloud, fit.objective)
    bounds = local_bounds(skel, config, pred)
    objective = local_cost_fn(skel, fit, obs, bounds)
    g_pred = encode(skel, bounds, pred)
    g_last = encode(skel, bounds, last)

    # the objective plus the motion prior: a limb the camera cannot see stays put; robust
    # (logarithmic) so that a limb may still jump to where the points show it
    def cost(genomes):
        return objective(genomes) + config.prior * jnp.mean(jnp.log1p(((genomes - g_pred) / config.std) ** 2), -1)

    P, G = config.population, config.generations
    ga = dataclasses.replace(fit, algorithm="ga", population=P, generations=G, std_init=config.std,
                             std_final=config.std_final, islands=1, staged=0.0)
    params = fit.params().replace(branch_reset_rate=jnp.float32(config.branch_reset_rate))
    algo, algo_params = make_algorithm(skel, ga, params)
    k_pop, k_init, k_run, k_sweep = jax.random.split(key, 4)
    noise = config.std * jax.random.normal(k_pop, (P - 2, g_pred.shape[0]))
    pop0 = jnp.clip(jnp.concatenate([g_pred[None], g_last[None], g_pred + noise]), 0.0, 1.0)
    f0 = cost(pop0)
    state = start_algorithm(algo, algo_params, k_init, pop0, f0)

    def generation(state, k):
        k_ask, k_tell = jax.random.split(k)
        pop, asked = algo.ask(k_ask, state, algo_params)
        state, _ = algo.tell(k_tell, pop, cost(pop), asked, algo_params)
        return state, state.best_fitness

    state, hist = jax.lax.scan(generation, state, jax.random.split(k_run, G - 1))
    best_g, best_f = state.best_solution, state.best_fitness
    if config.refine_steps > 0 and config.refine_count > 0:
        order = jnp.argsort(state.fitness)[: config.refine_count]
        g, f = refine(cost, state.population[order], jnp.int32(config.refine_steps), config.learning_rate)
        best_g, best_f = keep_better(g, f, best_g, best_f)
    if config.sweep_limbs:
        best_g, best_f = sweep_limbs(skel, config, cost, best_g, best_f, k_sweep, frame)
    history = jnp.concatenate([jnp.min(f0)[None], hist]).at[-1].set(best_f)
    if fit.tie_lengths:
        best_g = tie_lengths(skel, best_g)
    pose = decode(skel, bounds, best_g)
    # the cost reported (and compared with the global search's) is the objective alone
    return LocalFit(pose, best_g, forward_kinematics(skel, pose), objective(best_g[None])[0], history)


def sweep_limbs(skel: Skeleton, config: TrackConfig, cost, genome, genome_cost, key, frame):
    """The search's limb sweep (:func:`~jaxpose.search.sweep.sweep_rows`) over ``config.sweep_limbs``
    limbs, taken in turn: frame ``t`` sweeps rows ``t n, ..., t n + n - 1`` (mod K) of
    :func:`~jaxpose.search.sweep.sweep_masks`, so every limb is searched anew every ``K / n``
    frames.  Mutation steps as the global search's (``config.fit``): the draws are uniform."""
    all_masks = jnp.asarray(sweep_masks(skel))
    n = min(config.sweep_limbs, all_masks.shape[0])
    rows = (jnp.asarray(frame, jnp.int32) * n + jnp.arange(n)) % all_masks.shape[0]
    fit = dataclasses.replace(config.fit, population=config.population)
    return sweep_rows(skel, fit, cost, genome, genome_cost, key, config.learning_rate, all_masks[rows],
                      jnp.zeros(n, jnp.int32), hold, config.sweep_generations, config.sweep_steps)
