"""Limb sweeps: after the search, every limb searched again with the rest of the body held.

The islands settle the trunk early; a limb then caught in a wrong basin (an arm
folded behind the back while the points put it in front) stays there, because by
then mutation steps are small and Adam only descends.  A sweep takes the search's
best and, limb after limb down the tree (every link's subtree, trunk side first),
runs a small GA over that subtree's joint angles alone, from angles drawn
uniformly within their limits and the current ones, with every other gene held;
Adam then polishes its best few on every gene (unless the final refinement is
off), and the limb's new place is kept when it lowers the cost.  A systematic
search of each limb given the rest, where the GA's branch resets are rare random
jumps (docs/search.md, "Limb sweep").
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..skeleton import Skeleton
from .config import FitConfig
from .ga import BranchSwapGA, subtree_masks
from .genes import tie_lengths
from .memetic import hop_masks, keep_better
from .refine import refine

SWEEP_REFINE_TOP = 2  # the sweep's best individuals that Adam polishes, per limb
SWEEP_REFINE_STEPS = 30  # their Adam steps


def sweep_masks(skel: Skeleton) -> np.ndarray:
    """``(K, D)`` boolean: the joint-angle genes of every link's subtree that has any, in
    the skeleton's tree order (a parent's subtree before its children's)."""
    masks = hop_masks(skel)[:-1]  # the last row is the root's orientation
    return masks[masks.any(axis=1)]


def sweep_counts(skel: Skeleton, config: FitConfig) -> tuple[int, int]:
    """``(objective evaluations, gradient evaluations)`` of one sweep."""
    if not config.limb_sweep:
        return 0, 0
    K = len(sweep_masks(skel))
    top = min(SWEEP_REFINE_TOP, config.population)
    steps = SWEEP_REFINE_STEPS if config.final_refine_on else 0  # no refinement at all: no Adam here either
    return K * config.population * config.limb_sweep, K * top * steps


def limb_sweep(skel: Skeleton, config: FitConfig, cost, genome, genome_cost, key, learning_rate):
    """Sweep the limbs of ``genome (D,)`` (its cost ``genome_cost``) under ``cost(genomes (P, D)) -> (P,)``.

    Returns ``(genome, cost)``: never worse than the input.  ``config.limb_sweep``
    generations of ``config.population`` individuals per limb."""
    if config.tie_lengths:
        raw = cost
        cost = lambda g: raw(tie_lengths(skel, g))  # noqa: E731
    masks = jnp.asarray(sweep_masks(skel))
    P, G = config.population, config.limb_sweep
    D = genome.shape[-1]
    decay = (config.std_final / config.std_init) ** (1.0 / max(G, 1))
    schedule = lambda n: config.std_init * decay ** n  # noqa: E731
    # the limb's genes only: crossover and mutation pick among them, other genes are held
    algo = BranchSwapGA(P, jnp.zeros(D, jnp.float32), subtree_masks(skel), std_schedule=schedule,
                        elite_ratio=config.elite_ratio)
    # every child moves every gene of the limb (mutations elsewhere would be undone by the mask)
    params = algo.default_params.replace(mutation_rate=1.0, branch_mutation_rate=0.0, branch_reset_rate=0.1)
    top = min(SWEEP_REFINE_TOP, P)

    def one_limb(carry, inputs):
        g, f = carry
        mask, k = inputs
        k_pop, k_init, k_run = jax.random.split(k, 3)
        fresh = jax.random.uniform(k_pop, (P - 1, D), g.dtype)
        pop0 = jnp.concatenate([g[None], jnp.where(mask, fresh, g[None])])
        state = algo.init(k_init, pop0, cost(pop0), params)

        def generation(state, kg):
            k_ask, k_tell = jax.random.split(kg)
            pop, asked = algo.ask(k_ask, state, params)
            pop = jnp.where(mask, pop, g[None])
            state, _ = algo.tell(k_tell, pop, cost(pop), asked, params)
            return state, None

        state, _ = jax.lax.scan(generation, state, jax.random.split(k_run, G - 1)) if G > 1 else (state, None)
        best_g, best_f = state.best_solution, state.best_fitness
        if config.final_refine_on:
            order = jnp.argsort(state.fitness)[:top]
            rg, rf = refine(cost, state.population[order], jnp.int32(SWEEP_REFINE_STEPS), learning_rate)
            best_g, best_f = keep_better(rg, rf, best_g, best_f)
        return keep_better(best_g[None], best_f[None], g, f), None

    keys = jax.random.split(key, masks.shape[0])
    (g, f), _ = jax.lax.scan(one_limb, (genome, genome_cost), (masks, keys))
    return g, f
