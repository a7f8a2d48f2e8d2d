"""Islands: independent sub-populations vmapped side by side, and successive halving.

Islands are restarts: each settles on one root orientation early (the trunk is
searched first) and keeps it; halving then spends the budget on the promising ones,
keeping the best island of every distinct root orientation first (docs/search.md,
"Islands and successive halving").
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ..genome import genome_layout, root_rpy_values
from ..geometry import rpy_matrix
from ..skeleton import Skeleton
from .config import FitConfig
from .state import SHARED, SearchState


def island_map(config: FitConfig, fn):
    """``fn`` vmapped over the leading island axis when ``config.islands > 1``."""
    return fn if config.islands == 1 else jax.vmap(fn)


def per_island(config: FitConfig, fn, st: SearchState, *args):
    """``fn(st, *args)`` for one island, vmapped over the leading island axis of ``st``
    and ``args`` when ``config.islands > 1``.  The shared fields are not batched.  A
    :class:`SearchState` in ``fn``'s output (alone or in a tuple) gets them back."""
    if config.islands == 1:
        return fn(st, *args)
    shared = {n: getattr(st, n) for n in SHARED}
    return vmap_shared(shared, lambda s, *a: fn(s._replace(**shared), *a),
                       st._replace(**dict.fromkeys(SHARED)), *args)


def vmap_shared(shared: dict, fn, *args):
    """``jax.vmap(fn)(*args)``, ``shared`` (the :data:`SHARED` fields) left out of the
    batch: any :class:`SearchState` that ``fn`` returns gets them back unbatched."""
    out = jax.vmap(lambda *a: _map_states(fn(*a), lambda o: o._replace(**dict.fromkeys(SHARED))))(*args)
    return _map_states(out, lambda o: o._replace(**shared))


def _map_states(out, f):
    """``f`` applied to ``out`` if it is a :class:`SearchState`, or to the states in a tuple."""
    if isinstance(out, SearchState):
        return f(out)
    if type(out) is tuple:
        return tuple(_map_states(o, f) for o in out)
    return out


def halving_generations(config: FitConfig) -> tuple[int, ...]:
    """The generations after which the islands are halved (``FitConfig.halve_islands_at``,
    each rounded to the nearest end of an epoch; none at the very end)."""
    E, G = config.epoch, config.generations
    if config.islands < 2:
        return ()
    at = {E * max(1, round(f * G / E)) for f in config.halve_islands_at}
    return tuple(sorted(g for g in at if g < G))


def niche_leaders(rpy: jax.Array, cost: jax.Array, min_angle_deg: float) -> jax.Array:
    """Which of ``n`` islands lead a niche: no better island's root orientation (``rpy
    (n, 3)``, costs ``(n,)``; ties go to the lower index) lies within ``min_angle_deg``
    of theirs.  The best island always leads."""
    R = rpy_matrix(rpy)
    cos = (jnp.einsum("iab,jab->ij", R, R) - 1.0) / 2.0  # cos of the angle of R_i^T R_j
    near = cos > jnp.cos(jnp.deg2rad(min_angle_deg))
    n = cost.shape[0]
    c = jnp.where(jnp.isnan(cost), jnp.inf, cost)
    idx = jnp.arange(n)
    better = (c[None, :] < c[:, None]) | ((c[None, :] == c[:, None]) & (idx[None, :] < idx[:, None]))
    return ~jnp.any(better & near, axis=1)


def halving_order(skel: Skeleton, config: FitConfig, st: SearchState) -> jax.Array:
    """The islands from the first to keep to the first to replace: by best cost, with
    ``halve_niche_deg > 0`` the leaders of distinct root orientations
    (:func:`niche_leaders`) before the rest."""
    state = st.algo_state
    cost = state.best_fitness
    if not config.halve_niche_deg:
        return jnp.argsort(cost)
    i = genome_layout(skel).names.index("root_roll")
    g = jnp.clip(state.best_solution[:, i : i + 3], 0.0, 1.0)
    lo, hi = st.bounds.lo[i : i + 3], st.bounds.hi[i : i + 3]
    leader = niche_leaders(root_rpy_values(st.bounds, lo + g * (hi - lo)), cost, config.halve_niche_deg)
    return jnp.lexsort((jnp.where(jnp.isnan(cost), jnp.inf, cost), ~leader))


def halve_islands(skel: Skeleton, config: FitConfig, st: SearchState) -> SearchState:
    """The islands to replace (the worse half in :func:`halving_order`) take over the
    populations of the islands to keep, when the generation count is one of
    :func:`halving_generations`.

    Only the evolutionary state is copied: every island keeps its random key (so a
    copy and its original go separate ways from here) and its evaluation counts."""
    when = halving_generations(config)
    if not when:
        return st
    state = st.algo_state
    order = halving_order(skel, config, st)
    n, half = config.islands, config.islands // 2
    source = jnp.arange(n).at[order[n - half :]].set(order[:half])
    now = jnp.any(state.generation_counter[0] == jnp.asarray(when))
    copied = jax.tree_util.tree_map(lambda x: jnp.where(now, x[source], x), state)
    return st._replace(algo_state=copied)
