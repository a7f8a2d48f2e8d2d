"""The cost of a population of genomes: decode, forward kinematics, objective."""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp

from ..genome import decode
from ..kinematics import collision_pairs, forward_kinematics
from ..objective import CollisionPairs, ObjectiveConfig, population_cost
from ..skeleton import Skeleton
from .config import FitConfig
from .state import SearchState


def objective_pairs(skel: Skeleton, obj: ObjectiveConfig) -> CollisionPairs | None:
    """The collision term's pairs under ``obj`` (``None`` when the term is off)."""
    if obj.collision_weight == 0:
        return None
    return collision_pairs(skel, obj.collision_margin)


def population_cost_fn(skel: Skeleton, config: FitConfig, st: SearchState):
    """``cost(genomes (P, D), blocks=None) -> (P,)`` on ``st``'s cloud and bounds with its
    traced weights, ``+inf`` where not finite (``blocks``: see :func:`~jaxpose.objective.data_cost`)."""
    obj, obs, bounds = config.objective, st.obs, st.bounds
    weights = (st.params.free_space_weight, st.params.collision_weight)
    pairs = objective_pairs(skel, obj)

    def cost(genomes, blocks=None):
        poses = jax.vmap(partial(decode, skel, bounds))(genomes)
        links = jax.vmap(partial(forward_kinematics, skel))(poses)
        c = population_cost(obs, links.start, links.end, links.radius, obj, blocks, pairs, weights)
        return jnp.where(jnp.isfinite(c), c, jnp.inf)

    return cost
