"""Several answers: the best distinct poses a search found.

A limb the camera does not see can truly be in two places, and a search whose best
answer is wrong often holds the right one among its islands' populations.  The
hypotheses are the best individuals of all islands, cheapest first, each kept only
if it moves some capsule end further than ``min_move`` from every pose kept before
it; each is then refined like the final answer (docs/search.md, "Hypotheses").
"""

from __future__ import annotations

from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ..genome import decode
from ..kinematics import Links, forward_kinematics
from ..objective import cloud_spread
from ..skeleton import Pose, Skeleton
from .config import FitConfig
from .cost import population_cost_fn
from .genes import lock
from .refine import refine
from .state import SearchState

# Two poses are alike unless some capsule end moves by more than this fraction of the
# cloud's spread (about 9 cm for a person 2.8 m away).
MIN_MOVE = 0.2


class Hypotheses(NamedTuple):
    """The ``k`` best distinct poses, cheapest first (the first is the fit's answer)."""

    genome: jax.Array  # (k, D)
    cost: jax.Array  # (k,)
    pose: Pose  # leaves with a leading (k,) axis
    links: Links  # leaves with a leading (k,) axis


def distinct(ends: np.ndarray, costs: np.ndarray, k: int, min_move: float) -> list[int]:
    """Indices of up to ``k`` rows, by increasing cost, each of whose capsule ends
    ``ends (M, E, 3)`` lie further than ``min_move`` from those of every row taken
    before it in at least one end (non-finite costs are never taken)."""
    taken: list[int] = []
    for i in np.argsort(costs, kind="stable"):
        if len(taken) == k or not np.isfinite(costs[i]):
            break
        if all(np.max(np.linalg.norm(ends[i] - ends[j], axis=-1)) > min_move for j in taken):
            taken.append(int(i))
    return taken


def candidates(st: SearchState) -> tuple[jax.Array, jax.Array]:
    """Every island's population and costs ``(M, D)``, ``(M,)`` (its best point for
    algorithms without a population), with the best so far of each island."""
    state = st.algo_state
    best_g = state.best_solution.reshape(-1, state.best_solution.shape[-1])
    best_f = jnp.reshape(state.best_fitness, (-1,))
    if hasattr(state, "population") and hasattr(state, "fitness"):
        pop = state.population.reshape(-1, best_g.shape[-1])
        return jnp.concatenate([best_g, pop]), jnp.concatenate([best_f, state.fitness.reshape(-1)])
    return best_g, best_f


def hypotheses(skel: Skeleton, config: FitConfig, st: SearchState, answer, k: int,
               min_move: float = MIN_MOVE) -> Hypotheses:
    """The fit's ``answer`` (its :class:`~jaxpose.search.FitResult`) and up to ``k - 1`` other distinct
    poses from the finished search ``st`` (``config``: the static config it ran), each
    refined by ``config.final_refine_steps`` Adam steps.  Fewer than ``k`` when the
    islands found fewer distinct poses."""
    genomes, costs = candidates(st)
    genomes = jnp.concatenate([answer.genome[None], genomes])
    costs = np.array(jnp.concatenate([jnp.reshape(answer.cost, (1,)), costs]))
    costs[1:] = np.where(costs[1:] < costs[0], costs[0], costs[1:])  # the answer first, whatever round-off
    links = _links(skel, st.bounds, genomes)
    ends = np.concatenate([np.asarray(links.start), np.asarray(links.end)], axis=1)
    scale = float(cloud_spread(st.obs.cloud))
    take = distinct(ends, costs, k, min_move * scale)
    g, f = genomes[np.asarray(take, int)], jnp.asarray(costs[take])
    if len(take) > 1 and config.final_refine_steps > 0:
        g_ref, f_ref = _refine(skel, config, st, g[1:], jnp.int32(config.final_refine_steps))
        better = f_ref < f[1:]
        g = g.at[1:].set(jnp.where(better[:, None], g_ref, g[1:]))
        f = f.at[1:].set(jnp.where(better, f_ref, f[1:]))
        # refinement may carry two onto one optimum: keep the distinct ones, the answer first
        f_host = np.array(f)
        f_host[0] = np.nanmin(f_host) - 1.0
        links = _links(skel, st.bounds, g)
        keep = distinct(np.concatenate([np.asarray(links.start), np.asarray(links.end)], axis=1), f_host, k,
                        min_move * scale)
        g, f = g[np.asarray(keep, int)], f[np.asarray(keep, int)]
    poses = jax.vmap(lambda x: decode(skel, st.bounds, x))(g)
    links = jax.vmap(lambda p: forward_kinematics(skel, p))(poses)
    first = lambda many, one: many.at[0].set(one)  # noqa: E731  (the answer as the fit computed it)
    return Hypotheses(first(g, answer.genome), first(f, answer.cost), jax.tree_util.tree_map(first, poses, answer.pose),
                      jax.tree_util.tree_map(first, links, answer.links))


@jax.jit
def _links(skel: Skeleton, bounds, genomes) -> Links:
    return jax.vmap(lambda g: forward_kinematics(skel, decode(skel, bounds, jnp.clip(g, 0.0, 1.0))))(genomes)


@partial(jax.jit, static_argnames="config")
def _refine(skel: Skeleton, config: FitConfig, st: SearchState, genomes, steps):
    gen = st.algo_state.generation_counter.reshape(-1)[0]
    pop_cost = population_cost_fn(skel, config, _one_island(st))
    return refine(lambda G: pop_cost(lock(skel, config, st.bounds, gen, G)), genomes, steps, st.params.learning_rate)


def _one_island(st: SearchState) -> SearchState:
    """``st`` with only what the cost reads (the shared fields), whatever its island axis."""
    return st._replace(algo_state=None, key=None, objective_evaluations=None, gradient_evaluations=None, initial=None)
