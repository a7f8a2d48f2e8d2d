"""The paper's objective (equation 1) and the optional free-space and collision terms.

Modules: ``cloud`` (the cloud, its spread), ``config``, ``data`` (the data term's
kernel), ``free_space``, ``collision``; the total is here.

Data term, for a cloud of points ``p_n`` with weights ``w_n`` (padding has weight 0)::

    E_data = sum_n w_n ln(1 + d_n / sigma) / sum_n w_n
    d_n    = min_l | dist(p_n, segment_l) - r_l |

``d_n`` is the distance from ``p_n`` to the closest capsule *surface* (a point
inside a capsule is as far from the model as it is from that capsule's wall; with
``r_l = 0`` this is the distance to the segment, as in the paper).

``sigma`` (:func:`cloud_spread`) is the root-mean-square distance of the weighted
points from their weighted centroid, ``sqrt(sum_n w_n ||p_n - c||^2 / sum_n w_n)``:
our reading of the paper's "standard deviation of point distances".  A fixed value
can be given instead (``ObjectiveConfig.sigma``).

Free-space term (not in the paper; ``free_space_weight`` 0 disables it).  The data
term only asks that every observed point be near the model, so a link may float
in empty space at no cost.  For a cloud seen from a camera at the origin looking
along +z, every model point must lie *on or behind* the observed surface: a point
in front of the surface, or outside the silhouette, would have been seen.  The
term samples ``free_space_samples`` points along every capsule axis and charges
``ln(1 + min(gap, sigma) / sigma)`` for a point ``gap`` metres in front of the
observed surface (``ln 2`` outside the silhouette), averaged over the samples.
The observed surface is a coarse depth map of the cloud (:class:`FreeSpaceMap`).

Collision term (not in the paper; ``collision_weight`` 0 disables it).
Neither term above stops a limb the camera cannot see from lying inside the trunk,
where it costs nothing.  A body's parts do not interpenetrate, so for pairs of
capsules ``(i, j)`` the term charges ``sum_k ln(1 + max(0, c_k - d_k) / sigma)``,
``d_k`` the distance between the two axes and ``c_k = rho_k collision_margin
(r_i + r_j)`` the clearance they must keep.  The pairs are every two links but a
link and its parent.  ``rho_k`` in ``[0, 1]`` is the pair's distance in the rest
pose over its clearance (at most 1): a pair that overlaps in the rest pose (a
forearm resting on a thigh, parts designed to overlap) only has to stay as far
apart as it is there, and two links that start at one joint (``rho = 0``) are
never charged (:func:`jaxpose.kinematics.collision_pairs`).  The rest pose is
taken at the skeleton's own lengths (see docs/objective.md for what that means when
lengths are searched).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from .cloud import Cloud, cloud_centre, cloud_spread
from .collision import CollisionPairs, collision_cost
from .config import ObjectiveConfig
from .data import LINK_GROUP, data_cost, num_blocks, point_capsule_distance, spread_order, to_blocks
from .free_space import FreeSpaceMap, free_space_cost, free_space_map


class Observation(NamedTuple):
    """Everything the cost needs about one cloud, computed once per fit."""

    cloud: Cloud
    sigma: jax.Array
    fmap: FreeSpaceMap


def observe(cloud: Cloud, config: ObjectiveConfig = ObjectiveConfig()) -> Observation:
    """The cloud, its sigma and its free-space map.  sigma is ``config.sigma`` when given
    (used as it is), else ``cloud_spread(cloud) * config.sigma_factor`` (which may be traced)."""
    if config.sigma is None:
        sigma = cloud_spread(cloud) * config.sigma_factor
    else:
        sigma = jnp.asarray(config.sigma, jnp.float32)
    return Observation(cloud, sigma, free_space_map(cloud, config.free_space_grid))


def population_cost(obs: Observation, start, end, radius, config: ObjectiveConfig = ObjectiveConfig(), blocks=None,
                    pairs: CollisionPairs | None = None, weights=None):
    """Total cost ``(P,)`` of a population of posed capsules ``(P, L, 3)`` (``blocks``:
    the data term on that many blocks of points only, see :func:`data_cost`).  The
    collision term needs the skeleton's ``pairs`` (:func:`jaxpose.kinematics.collision_pairs`);
    without them it is left out.

    ``weights``: ``(free_space_weight, collision_weight)`` to use instead of
    ``config``'s, as numbers that may be traced (one compiled cost for every weight);
    a term whose weight in ``config`` is exactly 0 is left out of the program."""
    fs_w, col_w = (config.free_space_weight, config.collision_weight) if weights is None else weights
    cost = data_cost(obs.cloud, obs.sigma, start, end, radius, config.block, blocks)
    if config.free_space_weight != 0:
        cost = cost + fs_w * free_space_cost(obs.fmap, obs.sigma, start, end, config.free_space_samples, radius,
                                             config.max_range)
    if config.collision_weight != 0 and pairs is not None and len(pairs.i):
        cost = cost + col_w * collision_cost(pairs, obs.sigma, start, end, radius, config.collision_margin)
    return cost


def paper_cost(points, weights, start, end, radius, sigma=None) -> jax.Array:
    """Equation 1 for one posed model ``start, end (L, 3)``; a convenience wrapper."""
    cloud = Cloud(jnp.asarray(points, jnp.float32), jnp.asarray(weights, jnp.float32))
    s = cloud_spread(cloud) if sigma is None else sigma
    return data_cost(cloud, s, start[None], end[None], jnp.broadcast_to(radius, start.shape[:1])[None])[0]


__all__ = [
    "LINK_GROUP", "Cloud", "CollisionPairs", "FreeSpaceMap", "ObjectiveConfig", "Observation", "cloud_centre",
    "cloud_spread", "collision_cost", "data_cost", "free_space_cost", "free_space_map", "num_blocks", "observe",
    "paper_cost", "point_capsule_distance", "population_cost", "spread_order", "to_blocks",
]
