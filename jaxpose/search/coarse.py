"""Coarse-to-fine scoring (``FitConfig.coarse_points``): the GA scores a few blocks of
points early on, then rescores its population on all of them and goes on."""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp

from ..objective import num_blocks
from ..skeleton import Skeleton
from .config import FitConfig
from .cost import population_cost_fn
from .islands import per_island
from .state import SearchState


def coarse_switch(config: FitConfig, n_points: int) -> int | None:
    """The generation at which a coarse-to-fine GA goes over to every point (the end of
    an epoch), or ``None`` when it scores every point throughout."""
    if not config.coarse_points or coarse_blocks(config, n_points) >= num_blocks(n_points, config.objective.block):
        return None
    E = config.epoch
    g = E * max(1, round(config.coarse_until * config.generations / E))
    return g if g < config.generations else None


def coarse_blocks(config: FitConfig, n_points: int) -> int:
    """Blocks of ``objective.block`` points that hold ``coarse_points`` points."""
    B = min(config.objective.block, max(n_points, 1))
    return max(1, -(-config.coarse_points // B))


def blocks_at(config: FitConfig, n_points: int, generation):
    """Blocks of points the GA scores at ``generation`` (``None``: all, the plain kernel)."""
    switch = coarse_switch(config, n_points)
    if switch is None:
        return None
    return jnp.where(generation < switch, coarse_blocks(config, n_points),
                     num_blocks(n_points, config.objective.block))


def rescore_island(skel: Skeleton, config: FitConfig, st: SearchState) -> SearchState:
    """One island's population and best so far scored anew on every point."""
    state = st.algo_state
    both = jnp.concatenate([state.population, state.best_solution[None]])
    f = population_cost_fn(skel, config, st)(both)
    state = state.replace(fitness=f[:-1], best_fitness=f[-1])
    return st._replace(algo_state=state, objective_evaluations=st.objective_evaluations + both.shape[0])


def rescore_all(skel: Skeleton, config: FitConfig, st: SearchState) -> SearchState:
    """:func:`rescore_island` every island now (an anytime fit that ends before the switch)."""
    return per_island(config, partial(rescore_island, skel, config), st)


def rescore_at_switch(skel: Skeleton, config: FitConfig, st: SearchState) -> SearchState:
    """At the coarse-to-fine switch (:func:`coarse_switch`), :func:`rescore_island` every island."""
    switch = coarse_switch(config, st.obs.cloud.points.shape[-2])
    if switch is None:
        return st
    gen = st.algo_state.generation_counter if config.islands == 1 else st.algo_state.generation_counter[0]
    return jax.lax.cond(gen == switch, lambda s: rescore_all(skel, config, s), lambda s: s, st)
