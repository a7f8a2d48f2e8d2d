"""A genetic algorithm with branch-swap crossover, in evosax's ask/tell framework.

The genome is the flat, normalised vector of :mod:`jaxpose.skeleton` (every gene
in ``[0, 1]``).  One generation:

1. *Selection*: parents are drawn uniformly from the ``num_elites`` best of the
   current population (truncation selection).
2. *Branch-swap crossover* (probability ``crossover_rate``): the child copies the
   first parent, then takes every gene of one randomly chosen subtree — the joint
   angles and lengths of a link and of all links below it — from the second
   parent.  ``subtree_masks[k]`` (precomputed from the skeleton) marks those genes.
3. *Mutation*: Gaussian noise of standard deviation ``std`` (a decaying schedule)
   on each gene with probability ``mutation_rate``, or, with probability
   ``branch_mutation_rate``, on every gene of one random subtree; results are
   clipped to ``[0, 1]``.  Then, with probability ``branch_reset_rate``, every gene
   of one random subtree is drawn anew, uniformly in ``[0, 1]`` (a jump of a whole
   limb, whatever the step size).
4. *Elitism* (in ``tell``): the next population is the best ``population_size``
   of the ``num_keep`` best parents and all children, so the best individual is
   never lost.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
import optax
from evosax.algorithms.population_based.base import (
    Params as BaseParams,
    PopulationBasedAlgorithm,
    State as BaseState,
)
from evosax.core.fitness_shaping import identity_fitness_shaping_fn
from evosax.types import Fitness, Population, Solution
from flax import struct

from ..genome import genome_layout
from ..skeleton import Skeleton


@struct.dataclass
class State(BaseState):
    population: Population
    fitness: Fitness
    std: jax.Array


@struct.dataclass
class Params(BaseParams):
    crossover_rate: float
    mutation_rate: float
    branch_mutation_rate: float
    branch_reset_rate: float


def subtree_masks(skel: Skeleton) -> np.ndarray:
    """``(L, D)`` boolean: genes of link ``k`` and all links below it."""
    layout = genome_layout(skel)
    return np.stack([layout.gene_mask(skel.subtree(k)) for k in range(skel.num_links)])


def _pick(u, n: int):
    """An index in ``0 .. n - 1`` from a uniform number in ``[0, 1)``."""
    return jnp.minimum(jnp.floor(u * n).astype(jnp.int32), n - 1)


# Uniform numbers each operator consumes per child (one draw per generation feeds them all).
_SWAP_U = 2

# erf_inv(x) is finite on the open interval (-1, 1)
_OPEN_ONE = float(np.nextafter(np.float32(1), np.float32(0)))


def uniform_and_normal(key: jax.Array, shape: tuple[int, ...], num_normal: int) -> tuple[jax.Array, jax.Array]:
    """Uniform numbers in ``[0, 1)`` of ``shape`` and standard normals of
    ``shape[:-1] + (num_normal,)``, from a single random draw.

    The normals are ``sqrt(2) erf_inv(2 u - 1)`` of further uniforms (the way
    ``jax.random.normal`` makes them).  One draw instead of two: on CPU each
    threefry draw is a sizeable program to compile (about half a second), whatever
    its size.
    """
    u = jax.random.uniform(key, (*shape[:-1], shape[-1] + num_normal))
    v = jnp.clip(2.0 * u[..., shape[-1] :] - 1.0, -_OPEN_ONE, _OPEN_ONE)
    return u[..., : shape[-1]], np.float32(np.sqrt(2.0)) * jax.lax.erf_inv(v)


def _mutate_u(num_dims: int) -> int:
    return 3 + 2 * num_dims


def _branch_swap(u, parent_1, parent_2, masks, rate):
    """:func:`branch_swap` on pre-drawn uniforms ``u (2,)``."""
    mask = masks[_pick(u[0], masks.shape[0])] & (u[1] < rate)
    return jnp.where(mask, parent_2, parent_1)


def _mutate(u, noise, x, std, rate, branch_rate, masks, reset_rate):
    """:func:`mutate` on pre-drawn uniforms ``u (3 + 2 D,)`` and normals ``noise (D,)``."""
    D = x.shape[-1]
    gene_mask = u[3 : 3 + D] < rate
    branch_mask = masks[_pick(u[0], masks.shape[0])]
    mask = jnp.where(u[1] < branch_rate, branch_mask, gene_mask)
    y = jnp.clip(x + mask * std * noise, 0.0, 1.0)
    reset = branch_mask & (u[2] < reset_rate)
    return jnp.where(reset, u[3 + D :], y)


def branch_swap(key: jax.Array, parent_1: Solution, parent_2: Solution, masks: jax.Array, rate) -> Solution:
    """Child = ``parent_1`` with one random subtree's genes from ``parent_2`` (with prob. ``rate``)."""
    return _branch_swap(jax.random.uniform(key, (_SWAP_U,)), parent_1, parent_2, masks, rate)


def mutate(key: jax.Array, x: Solution, std, rate, branch_rate, masks: jax.Array, reset_rate=0.0) -> Solution:
    """Gaussian mutation of random genes or of one random subtree, clipped to ``[0, 1]``.

    With probability ``reset_rate`` the child instead draws every gene of one random
    subtree anew, uniformly in ``[0, 1]``: a jump that moves a whole limb out of a
    local optimum (e.g. an arm hidden inside the trunk) at any step size.
    """
    k_u, k_n = jax.random.split(key)
    u = jax.random.uniform(k_u, (_mutate_u(x.shape[-1]),))
    return _mutate(u, jax.random.normal(k_n, x.shape), x, std, rate, branch_rate, masks, reset_rate)


class BranchSwapGA(PopulationBasedAlgorithm):
    """Elitist GA with branch-swap crossover on a skeleton genome."""

    def __init__(
        self,
        population_size: int,
        solution: Solution,
        masks: np.ndarray,
        std_schedule: Callable = optax.constant_schedule(0.05),
        elite_ratio: float = 0.25,
        keep_ratio: float = 0.05,
        fitness_shaping_fn: Callable = identity_fitness_shaping_fn,
    ):
        super().__init__(population_size, solution, fitness_shaping_fn)
        self.masks = np.asarray(masks, bool)
        self.std_schedule = std_schedule
        self.elite_ratio = elite_ratio
        self.num_keep = max(1, int(keep_ratio * population_size))

    @property
    def _default_params(self) -> Params:
        return Params(crossover_rate=0.5, mutation_rate=0.15, branch_mutation_rate=0.3, branch_reset_rate=0.0)

    def _init(self, key: jax.Array, params: Params) -> State:
        return State(
            population=jnp.full((self.population_size, self.num_dims), jnp.nan),
            fitness=jnp.full((self.population_size,), jnp.inf),
            std=jnp.asarray(self.std_schedule(0), jnp.float32),
            best_solution=jnp.full((self.num_dims,), jnp.nan),
            best_fitness=jnp.inf,
            generation_counter=0,
        )

    def _ask(self, key: jax.Array, state: State, params: Params) -> tuple[Population, State]:
        order = jnp.argsort(state.fitness)
        elites = state.population[order[: self.num_elites]]
        # every random number of the generation in one draw (each draw is a sizeable
        # program: one per operator and child made the step slow to compile)
        P, D, E = self.population_size, self.num_dims, self.num_elites
        u, noise = uniform_and_normal(key, (P, 2 + _SWAP_U + _mutate_u(D)), D)
        masks = jnp.asarray(self.masks)
        parent_1, parent_2 = elites[_pick(u[:, 0], E)], elites[_pick(u[:, 1], E)]
        children = jax.vmap(_branch_swap, in_axes=(0, 0, 0, None, None))(
            u[:, 2 : 2 + _SWAP_U], parent_1, parent_2, masks, params.crossover_rate
        )
        children = jax.vmap(_mutate, in_axes=(0, 0, 0, None, None, None, None, None))(
            u[:, 2 + _SWAP_U :], noise, children, state.std, params.mutation_rate,
            params.branch_mutation_rate, masks, params.branch_reset_rate,
        )
        return children, state

    def _tell(self, key, population: Population, fitness: Fitness, state: State, params: Params) -> State:
        fitness = jnp.where(jnp.isnan(fitness), jnp.inf, fitness)
        order = jnp.argsort(state.fitness)[: self.num_keep]
        pool = jnp.concatenate([state.population[order], population])
        pool_fit = jnp.concatenate([state.fitness[order], fitness])
        keep = jnp.argsort(pool_fit)[: self.population_size]
        return state.replace(
            population=pool[keep],
            fitness=pool_fit[keep],
            std=jnp.asarray(self.std_schedule(state.generation_counter + 1), jnp.float32),
        )
