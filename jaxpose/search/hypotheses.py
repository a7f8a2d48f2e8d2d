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

from .._xla_flags import fast_compile_options
from ..genome import decode
from ..kinematics import Links, forward_kinematics
from ..objective import cloud_spread
from ..skeleton import Pose, Skeleton
from .config import FitConfig
from .memetic import refine_rows
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
    poses from the finished search ``st`` (``config``: the static config it ran), refined like
    the answer (when the final refinement is on).  Fewer than ``k`` when the islands found
    fewer distinct poses.  NumPy arrays; every program runs at shapes fixed by the config and
    ``k``, so a second image compiles nothing.  The alternatives' refinement is not counted
    in the fit's evaluations."""
    genomes, costs, ends, spread = _candidate_ends(skel, config, st, answer.genome, answer.cost)
    costs = np.array(costs)
    costs[1:] = np.maximum(costs[1:], costs[0])  # the answer first, whatever round-off
    min_move = min_move * float(spread)
    take = distinct(np.asarray(ends), costs, k, min_move)
    take = np.asarray(take + [take[-1]] * (k - len(take)), np.int32)  # padded to k rows: one shape
    g, f, ends, poses, links = _refined(skel, config, st, jnp.asarray(genomes)[take], jnp.asarray(costs)[take])
    f = np.array(f)
    f[0] = -np.inf  # the answer first; the others by cost, distinct after refinement too
    keep = np.asarray(distinct(np.asarray(ends), np.where(np.isfinite(f), f, np.nanmin(f[1:]) - 1), k, min_move), int)
    rows = lambda tree: jax.tree_util.tree_map(lambda x: np.asarray(x)[keep], tree)  # noqa: E731
    first = lambda many, one: np.concatenate([np.asarray(one)[None], many[1:]])  # noqa: E731  (as the fit computed)
    return Hypotheses(first(rows(g), answer.genome), first(np.array(f)[keep], answer.cost),
                      jax.tree_util.tree_map(first, rows(poses), answer.pose),
                      jax.tree_util.tree_map(first, rows(links), answer.links))


def with_answers(hyp: Hypotheses, answers: list, spread: float, k: int, min_move: float = MIN_MOVE) -> Hypotheses:
    """``hyp`` and the ``answers`` of a portfolio's other searches (:class:`~jaxpose.search.FitResult`),
    each kept where it is distinct from every pose kept before it (by cost, the fit's answer
    first), at most ``k`` in all: another search's answer is another reading of the points."""
    as_np = lambda tree: jax.tree_util.tree_map(np.asarray, tree)  # noqa: E731
    rows = [jax.tree_util.tree_map(lambda x: np.asarray(x)[i], hyp) for i in range(len(hyp.cost))]
    rows += [Hypotheses(as_np(r.genome), as_np(r.cost), as_np(r.pose), as_np(r.links)) for r in answers]
    costs = np.array([float(r.cost) for r in rows])
    finite = costs[np.isfinite(costs)]
    costs[0] = (finite.min() if finite.size else 0.0) - 1.0  # the fit's answer stays first
    ends = np.stack([np.concatenate([r.links.start, r.links.end], axis=0) for r in rows])
    keep = distinct(ends, costs, k, min_move * float(spread))
    return jax.tree_util.tree_map(lambda *x: np.stack(x), *[rows[i] for i in keep])


@partial(jax.jit, static_argnames="config", compiler_options=fast_compile_options())
def _candidate_ends(skel: Skeleton, config: FitConfig, st: SearchState, genome, cost):
    """The answer and every island's candidates: genomes, costs, capsule ends ``(M, 2 L, 3)``, the cloud's spread."""
    genomes, costs = candidates(st)
    genomes = jnp.concatenate([genome[None], genomes])
    costs = jnp.concatenate([jnp.reshape(cost, (1,)), costs])
    links = jax.vmap(lambda g: forward_kinematics(skel, decode(skel, st.bounds, jnp.clip(g, 0.0, 1.0))))(genomes)
    return genomes, costs, jnp.concatenate([links.start, links.end], axis=1), cloud_spread(st.obs.cloud)


@partial(jax.jit, static_argnames="config", compiler_options=fast_compile_options())
def _refined(skel: Skeleton, config: FitConfig, st: SearchState, g, f):
    """Rows ``1..`` of ``g (k, D)`` refined as the answer was (kept where better), then every
    row's pose, links and capsule ends."""
    if config.final_refine_on:
        g_ref, f_ref = refine_rows(skel, config, st, g[1:], jnp.int32(config.final_refine_steps))
        better = f_ref < f[1:]
        g = g.at[1:].set(jnp.where(better[:, None], g_ref, g[1:]))
        f = f.at[1:].set(jnp.where(better, f_ref, f[1:]))
    poses = jax.vmap(lambda x: decode(skel, st.bounds, jnp.clip(x, 0.0, 1.0)))(g)
    links = jax.vmap(lambda p: forward_kinematics(skel, p))(poses)
    return g, f, jnp.concatenate([links.start, links.end], axis=1), poses, links
