"""Gradient refinement inside the search: the memetic step that ends every GA epoch
and the final refinement of the best individuals (both :func:`refine_top`)."""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp

from ..skeleton import Skeleton
from .config import FitConfig
from .cost import population_cost_fn
from .genes import lock
from .islands import per_island
from .refine import refine
from .state import SearchState


def candidates(config: FitConfig, m: int, state):
    """The ``m`` fittest of the GA's population (``order``: their rows), or the best
    point of the other algorithms."""
    if config.algorithm == "ga":  # elitism keeps the best in the population
        order = jnp.argsort(state.fitness)[:m]
        return order, state.population[order]
    return jnp.zeros((1,), jnp.int32), state.best_solution[None]


def refine_top(skel: Skeleton, config: FitConfig, st: SearchState, m: int, steps):
    """Adam-refine every island's ``m`` best candidates (:func:`candidates`).  Returns
    ``(order, genomes, costs)`` (``order``: the candidates' rows in the population),
    with a leading island axis when there are islands.

    The islands' candidates are refined as one batch (every row's refinement is its
    own; the cloud is the same).  Genes locked at the current generation stay
    locked.  ``steps`` is traced, so the memetic step and the final refinement share
    one compiled program when they refine as many candidates.
    """
    pick = partial(candidates, config, m)
    order, cand = pick(st.algo_state) if config.islands == 1 else jax.vmap(pick)(st.algo_state)
    g, f = refine_rows(skel, config, st, cand.reshape(-1, cand.shape[-1]), steps)
    return order, g.reshape(cand.shape), f.reshape(cand.shape[:-1])


def refine_rows(skel: Skeleton, config: FitConfig, st: SearchState, rows, steps):
    """Adam-refine genomes ``rows (m, D)`` on ``st``'s cloud with its traced settings; genes
    locked at the current generation stay locked.  Returns the best iterates and their costs."""
    gen = st.algo_state.generation_counter.reshape(-1)[0]
    pop_cost = population_cost_fn(skel, config, st)
    return refine(lambda G: pop_cost(lock(skel, config, st.bounds, gen, G)), rows, steps, st.params.learning_rate)


def keep_better(g, f, best_g, best_f):
    """The best of refined rows ``g (m, D)``, ``f (m,)`` if it beats ``(best_g, best_f)``."""
    i = jnp.argmin(f)
    better = f[i] < best_f
    return jnp.where(better, g[i], best_g), jnp.where(better, f[i], best_f)


def _memetic_apply_island(skel: Skeleton, config: FitConfig, st: SearchState, order, g, f) -> SearchState:
    """Write refined individuals back into one island's population (and its best so far)."""
    state = st.algo_state
    best_g, best_f = keep_better(g, f, state.best_solution, state.best_fitness)
    locked = partial(lock, skel, config, st.bounds, state.generation_counter)
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
        return refine_fn(skel, config, st, config.final_count, jnp.int32(config.final_refine_steps))
    return None
