"""What a fit returns (:class:`FitResult`) and carries between its compiled epochs (:class:`SearchState`)."""

from __future__ import annotations

from typing import Any, NamedTuple

import jax

from ..genome import Bounds
from ..kinematics import Links
from ..objective import Observation
from ..skeleton import Pose
from .config import FitParams


class FitResult(NamedTuple):
    """What a fit returns (a pytree; every leaf gains a batch axis under vmap).

    ``distance_evaluations`` counts point-to-capsule distances:
    ``(objective + gradient evaluations) * N * L``, ``N`` the cloud's array size."""

    pose: Pose  # best parameters, physical units
    genome: jax.Array  # (D,) best genome
    links: Links  # posed links of the best parameters (camera frame)
    cost: jax.Array  # () final cost
    history: jax.Array  # (generations,) best cost after each generation
    objective_evaluations: jax.Array  # () int
    gradient_evaluations: jax.Array  # () int
    distance_evaluations: jax.Array  # () float (can exceed int32)
    wall_time: jax.Array  # () seconds, filled in by Fitter (0 inside jit)
    hypotheses: Any = None  # the k best distinct poses (search.hypotheses.Hypotheses) when asked for


class SearchState(NamedTuple):
    """The search between epochs.  With islands, every field but the shared ones
    (:data:`SHARED`: the same for all islands, stored once) has a leading island axis.

    ``initial`` is the initial population; the first generation evaluates it (while
    ``objective_evaluations`` is 0, ``algo_state`` is a placeholder)."""

    algo_state: Any
    key: jax.Array
    obs: Observation
    bounds: Bounds
    params: FitParams
    objective_evaluations: jax.Array
    gradient_evaluations: jax.Array
    initial: jax.Array


# Fields every island reads alike: the cloud, the genome's bounds, the traced settings.
SHARED = ("obs", "bounds", "params")
