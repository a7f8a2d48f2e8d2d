"""Where the search starts: the genes' bounds for a cloud and the initial population.

The root goes near the cloud's centre at the scale of the cloud's spread; half the
population's roots align the model's principal axes with the cloud's (docs/search.md,
"Initialisation").
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..genome import Bounds, encode, genome_bounds, genome_layout, held_bounds, root_rpy_values, window
from ..geometry import axis_angle_matrix, matrix_to_rpy, rpy_matrix
from ..objective import Observation, cloud_centre, cloud_spread
from ..rest_model import RestModel, principal_axes, rest_model
from ..skeleton import Skeleton, rest_pose
from .config import FitConfig, FitParams
from .ga import uniform_and_normal


def aligned_root(flip, skel: Skeleton, obs: Observation, scale, rest: RestModel | None = None, spin=0.0):
    """A root pose ``(translation, rpy)`` that aligns the rest-pose model's principal
    axes with the cloud's, then turns it by ``spin`` radians about one of them.

    The sign of each axis is ambiguous: ``flip (2,)`` (booleans) flips the first two
    axes, the third follows, so the four choices are the four proper rotations.
    Only one axis is reliable in a single view (a surface seen from one side says
    little about the other two), so hypotheses spin about ``RestModel.spin_axis``:
    the major axis of an elongated model, the normal of a flat one.  The model's
    centroid lands half a mean link radius behind the cloud's centroid (the cloud
    only covers the surface facing the camera).
    """
    rest = rest or rest_model(skel)
    m_c, M = rest.centre, rest.axes
    c_c, C = principal_axes(obs.cloud.points, obs.cloud.weights)[:2]
    s12 = jnp.where(flip, -1.0, 1.0)
    s3 = s12[0] * s12[1] * jnp.sign(jnp.linalg.det(C) * jnp.linalg.det(M))
    R = (C * jnp.concatenate([s12, s3[None]])[None]) @ M.T
    R = axis_angle_matrix(C[:, rest.spin_axis], spin) @ R
    ray = c_c / jnp.maximum(jnp.linalg.norm(c_c), 1e-9)
    centre = c_c + ray * 0.5 * scale * jnp.mean(skel.radius)
    return centre - scale * R @ m_c, matrix_to_rpy(R)


def turned_roots(skel: Skeleton, rpy: jax.Array, turns: int, rest: RestModel | None = None) -> jax.Array:
    """``(turns, 3)``: the root orientation ``rpy`` turned half a turn about each of the
    rest model's principal axes (in the model's frame), the spin axis first.  With the
    orientation these are the four proper rotations that keep the principal axes: the
    ambiguity :func:`aligned_root` draws from, about an answer instead of the cloud."""
    rest = rest or rest_model(skel)
    R = rpy_matrix(rpy)
    order = (rest.spin_axis + jnp.arange(3)) % 3
    return jnp.stack([matrix_to_rpy(R @ axis_angle_matrix(rest.axes[:, order[i]], jnp.pi)) for i in range(turns)])


def initial_scale(skel: Skeleton, obs: Observation, rest: RestModel | None = None) -> jax.Array:
    """The scale at which the rest-pose model spreads like the cloud."""
    s0 = cloud_spread(obs.cloud) / (rest or rest_model(skel)).spread
    return jnp.clip(s0, skel.scale_lo, skel.scale_hi)


def search_bounds(skel: Skeleton, obs: Observation, config: FitConfig, rest: RestModel | None = None,
                  params: FitParams | None = None) -> Bounds:
    """Gene ranges for this cloud: root within the cloud's extent, scale near :func:`initial_scale`
    (``config.scale`` when it is known);
    with ``params.root_window > 0`` the root's orientation within that window about ``params.root_rpy``
    (a relative turn: :func:`~jaxpose.genome.held_bounds`)."""
    centre = cloud_centre(obs.cloud)
    d = jnp.sqrt(jnp.sum((obs.cloud.points - centre) ** 2, -1))
    extent = jnp.maximum(jnp.max(jnp.where(obs.cloud.weights > 0, d, 0.0)), 1e-3)
    bounds = genome_bounds(skel, centre, extent)
    i = genome_layout(skel).names.index("scale")
    if config.scale is not None:  # known: the gene spans the one value
        s = jnp.asarray(config.scale, jnp.float32)
        bounds = Bounds(bounds.lo.at[i].set(s), bounds.hi.at[i].set(s))
    elif config.scale_window:
        lo, hi = window(initial_scale(skel, obs, rest), skel.scale_lo, skel.scale_hi, config.scale_window)
        bounds = Bounds(bounds.lo.at[i].set(lo), bounds.hi.at[i].set(hi))
    if params is not None:
        bounds = held_bounds(bounds, params.root_rpy, params.root_window, params.root_window > 0)
    return bounds


def initial_population(key, skel: Skeleton, obs: Observation, bounds: Bounds, config: FitConfig,
                       params: FitParams, rest: RestModel | None = None) -> jax.Array:
    """Data-driven initial genomes ``(population, D)``: root near the cloud's centre,
    scale from the cloud's spread against the model's, orientation and joint angles
    uniform within limits, lengths near their rest values.  A fraction
    ``init_pca_fraction`` gets a root aligned with the cloud's principal axes instead,
    turned by a uniform angle about the most reliable one (:func:`aligned_root`)."""
    rest = rest or rest_model(skel)
    layout = genome_layout(skel)
    P, D = config.population, layout.size
    # one draw for everything (each random draw is a sizeable program to compile); the
    # root-translation and length genes are disjoint, so they share one normal array
    u, z = uniform_and_normal(key, (P, D + 3), D + 7)
    g = u[:, :D]
    names = layout.names
    root_t = np.array([n in ("root_tx", "root_ty", "root_tz") for n in names])
    scale_i = names.index("scale")
    is_len = np.array([n.endswith(".length") for n in names])
    g = jnp.where(root_t, 0.5 + params.init_root_std * z[:, :D], g)
    s0 = initial_scale(skel, obs, rest) if config.scale is None else jnp.asarray(config.scale, jnp.float32)
    s_lo, s_hi = bounds.lo[scale_i], bounds.hi[scale_i]
    s_gene = (s0 * jnp.exp(0.15 * z[:, D]) - s_lo) / jnp.maximum(s_hi - s_lo, 1e-9)
    g = g.at[:, scale_i].set(s_gene)
    rest_g = encode(skel, bounds, rest_pose(skel))
    g = jnp.where(is_len, rest_g + 0.1 * z[:, :D], g)
    n_pca = int(round(config.init_pca_fraction * P))
    if n_pca > 0:
        flips, spin = u[:n_pca, D : D + 2] < 0.5, 2.0 * jnp.pi * u[:n_pca, D + 2]
        t, rpy = jax.vmap(lambda f, a: aligned_root(f, skel, obs, s0, rest, a))(flips, spin)
        rpy = root_rpy_values(bounds, rpy, inverse=True)  # a turn search's genes are relative
        span = jnp.maximum(bounds.hi[:6] - bounds.lo[:6], 1e-9)
        root_g = (jnp.concatenate([t, rpy], 1) - bounds.lo[:6]) / span
        root_g = root_g + params.init_pca_std * z[:n_pca, D + 1 :]
        g = g.at[:n_pca, :6].set(root_g)
    return jnp.clip(g, 0.0, 1.0)
