"""The cost of a population of genomes: decode, forward kinematics, objective."""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp

from ..genome import decode
from ..kinematics import collision_pairs, forward_kinematics
from ..objective import CollisionPairs, ObjectiveConfig, Observation, population_cost
from ..skeleton import Pose, Skeleton
from .config import FitConfig, FitParams
from .state import SearchState


def objective_pairs(skel: Skeleton, obj: ObjectiveConfig) -> CollisionPairs | None:
    """The collision term's pairs under ``obj`` (``None`` when the term is off)."""
    if obj.collision_weight == 0:
        return None
    return collision_pairs(skel, obj.collision_margin)


def pose_cost(skel: Skeleton, obs: Observation, poses: Pose, obj: ObjectiveConfig, params: FitParams | None = None,
              blocks=None) -> jax.Array:
    """The search's cost ``(P,)`` of ``poses`` (batched, ``(P, ...)`` leaves): the objective on their
    capsules with ``params``' traced weights (default ``obj``'s): one place for the search and tracking."""
    links = jax.vmap(partial(forward_kinematics, skel))(poses)
    weights = None if params is None else (params.free_space_weight, params.collision_weight)
    return population_cost(obs, links.start, links.end, links.radius, obj, blocks, objective_pairs(skel, obj),
                           weights)


def population_cost_fn(skel: Skeleton, config: FitConfig, st: SearchState):
    """``cost(genomes (P, D), blocks=None) -> (P,)`` on ``st``'s cloud and bounds with its
    traced weights, ``+inf`` where not finite (``blocks``: see :func:`~jaxpose.objective.data_cost`)."""
    obj, obs, bounds = config.objective, st.obs, st.bounds

    def cost(genomes, blocks=None):
        poses = jax.vmap(partial(decode, skel, bounds))(genomes)
        c = pose_cost(skel, obs, poses, obj, st.params, blocks)
        return jnp.where(jnp.isfinite(c), c, jnp.inf)

    return cost
