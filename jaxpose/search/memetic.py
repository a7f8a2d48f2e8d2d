"""Gradient refinement inside the search: the memetic step that ends every GA epoch
and the final refinement of the best individuals (both :func:`refine_top`)."""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from ..genome import genome_layout
from ..skeleton import Skeleton
from .config import FitConfig
from .cost import population_cost_fn
from .ga import subtree_masks
from .genes import lock
from .islands import per_island
from .refine import refine
from .state import SearchState


def hop_masks(skel: Skeleton) -> np.ndarray:
    """``(L + 1, D)`` boolean: the joint-angle genes of every link's subtree, and last
    the root's orientation genes: what one limb hop draws anew."""
    names = genome_layout(skel).names
    angle = np.array([".q" in n for n in names])
    root = np.array([n in ("root_roll", "root_pitch", "root_yaw") for n in names])
    return np.concatenate([subtree_masks(skel) & angle[None], root[None]])


def limb_hops(skel: Skeleton, key, genome, n: int):
    """``n`` copies of ``genome (D,)``, each with one random entry of :func:`hop_masks`
    drawn anew, uniformly within the genes' bounds."""
    masks = jnp.asarray(hop_masks(skel))
    k_pick, k_draw = jax.random.split(key)
    which = jax.random.randint(k_pick, (n,), 0, masks.shape[0])
    fresh = jax.random.uniform(k_draw, (n, genome.shape[-1]), genome.dtype)
    return jnp.where(masks[which], fresh, genome[None])


def candidates(skel: Skeleton, config: FitConfig, rows: int | tuple[int, int], state, key):
    """What an island refines, ``rows = (m, hops)`` (or ``m``: no hops): the ``m`` fittest of the GA's
    population and ``hops`` limb hops of its best (:func:`limb_hops`) that will take
    the places of the worst; ``order``: the rows they go to.  Other algorithms: their
    best point."""
    m, hops = rows if isinstance(rows, tuple) else (rows, 0)
    if config.algorithm == "ga":  # elitism keeps the best in the population
        ranked = jnp.argsort(state.fitness)
        order, cand = ranked[:m], state.population[ranked[:m]]
        if hops:
            hop_key = jax.random.fold_in(key, state.generation_counter)  # the island's stream is left alone
            order = jnp.concatenate([order, ranked[::-1][:hops]])
            cand = jnp.concatenate([cand, limb_hops(skel, hop_key, state.best_solution, hops)])
        return order, cand
    return jnp.zeros((1,), jnp.int32), state.best_solution[None]


def refine_top(skel: Skeleton, config: FitConfig, st: SearchState, m: int | tuple[int, int], steps):
    """Adam-refine every island's candidates (:func:`candidates`, ``m = (best, hops)`` or ``best``).
    Returns ``(order, genomes, costs)`` (``order``: the candidates' rows in the
    population), with a leading island axis when there are islands.

    The islands' candidates are refined as one batch (every row's refinement is its
    own; the cloud is the same).  Genes locked at the current generation stay
    locked.  ``steps`` is traced, so the memetic step and the final refinement share
    one compiled program when they refine as many candidates.
    """
    pick = partial(candidates, skel, config, m)
    order, cand = pick(st.algo_state, st.key) if config.islands == 1 else jax.vmap(pick)(st.algo_state, st.key)
    g, f = refine_rows(skel, config, st, cand.reshape(-1, cand.shape[-1]), steps)
    return order, g.reshape(cand.shape), f.reshape(cand.shape[:-1])


def refine_rows(skel: Skeleton, config: FitConfig, st: SearchState, rows, steps):
    """Adam-refine genomes ``rows (m, D)`` on ``st``'s cloud with its traced settings; genes
    locked at the current generation stay locked.  Returns the best iterates and their costs."""
    gen = st.algo_state.generation_counter.reshape(-1)[0]
    pop_cost = population_cost_fn(skel, config, st)
    return refine(lambda G: pop_cost(lock(skel, config, st.bounds, gen, G, st.params.staged)), rows, steps,
                  st.params.learning_rate)


def keep_better(g, f, best_g, best_f):
    """The best of refined rows ``g (m, D)``, ``f (m,)`` if it beats ``(best_g, best_f)``."""
    i = jnp.argmin(f)
    better = f[i] < best_f
    return jnp.where(better, g[i], best_g), jnp.where(better, f[i], best_f)


def _memetic_apply_island(skel: Skeleton, config: FitConfig, st: SearchState, order, g, f) -> SearchState:
    """Write refined individuals back into one island's population (and its best so far)."""
    state = st.algo_state
    best_g, best_f = keep_better(g, f, state.best_solution, state.best_fitness)
    locked = partial(lock, skel, config, st.bounds, state.generation_counter, staged=st.params.staged)
    state = state.replace(
        population=locked(state.population.at[order].set(g)),
        fitness=state.fitness.at[order].set(f),
        best_solution=locked(best_g),
        best_fitness=best_f,
    )
    grads = st.gradient_evaluations + g.shape[0] * config.memetic_steps
    return st._replace(algo_state=state, gradient_evaluations=grads)


def memetic_apply(skel: Skeleton, config: FitConfig, st: SearchState, refined, history):
    """Apply :func:`refine_top`'s result as the memetic step; the epoch's last
    history entry becomes the best cost after it."""
    st = per_island(config, lambda s, o, g, f: _memetic_apply_island(skel, config, s, o, g, f), st, *refined)
    return st, history.at[-1].set(jnp.min(st.algo_state.best_fitness))


def final_refine(skel: Skeleton, config: FitConfig, st: SearchState, refine_fn=refine_top):
    """The final refinement's candidates refined (``refine_fn``: :func:`refine_top` or
    its compiled program), or ``None`` when it is off."""
    if config.final_refine_on:
        return refine_fn(skel, config, st, config.final_rows, jnp.int32(config.final_refine_steps))
    return None
