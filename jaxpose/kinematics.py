"""Forward kinematics: :class:`~jaxpose.skeleton.Pose` -> world frames and capsules.

Pure JAX, jit-compiled by the caller, vmappable over populations and batches.
Local joint rotations are computed for all links in one vectorised call, then
composed down the tree one depth level at a time (a scan over the static levels).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .geometry import axis_angle_matrix, rpy_matrix, segment_distance
from .objective import CollisionPairs
from .skeleton import Pose, Skeleton, rest_pose


class Links(NamedTuple):
    """Every link's world frame and capsule, in metres (camera frame for fits)."""

    R_world_link: jax.Array  # (..., L, 3, 3)
    origin: jax.Array  # (..., L, 3) joint anchor
    start: jax.Array  # (..., L, 3) capsule start
    end: jax.Array  # (..., L, 3) capsule end
    radius: jax.Array  # (..., L)


def joint_rotations(skel: Skeleton, angles: jax.Array) -> jax.Array:
    """``R_rest @ R_joint(q)`` for every link: ``(L, 3, 3)``."""
    jt = np.array(skel.joint_types)
    ball = rpy_matrix(angles)
    hinge = axis_angle_matrix(skel.axis, angles[:, 0])
    eye = jnp.broadcast_to(jnp.eye(3, dtype=angles.dtype), ball.shape)
    Rj = jnp.where((jt == "ball")[:, None, None], ball, jnp.where((jt == "hinge")[:, None, None], hinge, eye))
    return skel.rest_rotation @ Rj


def _mat3(a, b):
    """Batched 3x3 products as broadcast sums: XLA:CPU mis-lays out the batched
    ``dot_general`` that nested vmaps (islands x population) make of ``a @ b``."""
    return jnp.sum(a[..., :, :, None] * b[..., None, :, :], -2)


def _matvec(R, v):
    """Batched ``R @ v`` for ``R (..., 3, 3)``, ``v (..., 3)`` (an ``einsum``: a
    broadcast sum ran slower; see docs/performance.md)."""
    return jnp.einsum("...ij,...j->...i", R, v)


def _compose(levels, parents, R_root, root_t, R_local, anchor):
    """World frames ``(R_w (L, 3, 3), t_w (L, 3))``, composed down the tree one depth
    level at a time by a ``lax.scan`` over the levels padded to the widest one.

    Frames live in an array of ``L + 1 + W`` slots: the links, the root frame (slot
    ``L``) and ``W`` scratch slots that the padding entries of a level write to.
    A scan, not an unrolled loop over the levels: its program does not grow with
    the depth, and it compiles to fewer kernels even for shallow trees, so the
    search compiles faster and runs as fast (see docs/performance.md).
    """
    L = len(parents)
    D, W = len(levels), max(len(level) for level in levels)
    root = L
    idx_tab = np.tile(np.arange(L + 1, L + 1 + W), (D, 1))
    par_tab = np.full((D, W), root)
    for k, level in enumerate(levels):
        lev = np.asarray(level)
        idx_tab[k, : len(lev)] = lev
        par_tab[k, : len(lev)] = np.where(parents[lev] < 0, root, parents[lev])
    dt = R_local.dtype
    R_loc = jnp.concatenate([R_local, jnp.broadcast_to(jnp.eye(3, dtype=dt), (1 + W, 3, 3))])
    anc = jnp.concatenate([anchor.astype(dt), jnp.zeros((1 + W, 3), dt)])
    R0 = jnp.zeros((L + 1 + W, 3, 3), dt).at[root].set(jnp.asarray(R_root, dt))
    t0 = jnp.zeros((L + 1 + W, 3), dt).at[root].set(jnp.asarray(root_t, dt))

    def step(carry, xs):
        R, t = carry
        idx, p = xs
        R_p, t_p = R[p], t[p]
        R = R.at[idx].set(_mat3(R_p, R_loc[idx]), unique_indices=True)
        t = t.at[idx].set(t_p + _matvec(R_p, anc[idx]), unique_indices=True)
        return (R, t), None

    tabs = (jnp.asarray(idx_tab, jnp.int32), jnp.asarray(par_tab, jnp.int32))
    (R_w, t_w), _ = jax.lax.scan(step, (R0, t0), tabs)
    return R_w[:L], t_w[:L]


def forward_kinematics(skel: Skeleton, pose: Pose) -> Links:
    """World-frame frames and capsule end points of every link for one pose.

    Use ``jax.vmap(forward_kinematics, in_axes=(None, 0))`` for a population.
    """
    L = skel.num_links
    parents = np.asarray(skel.parents)
    scale = pose.scale
    R_root = rpy_matrix(pose.root_rpy)
    R_local = joint_rotations(skel, pose.angles)
    par = np.maximum(parents, 0)
    parent_tip = skel.seg_start[par] + pose.lengths[par][:, None] * skel.seg_dir[par]
    parent_tip = jnp.where((parents >= 0)[:, None], parent_tip, 0.0)
    anchor = skel.offset + skel.attach[:, None] * parent_tip
    slide = np.array([jt == "slide" for jt in skel.joint_types])
    if slide.any():  # a slide moves its link's anchor along the axis (rest frame) by its value
        moved = _matvec(skel.rest_rotation, skel.axis) * pose.angles[:, :1]
        anchor = anchor + jnp.where(slide[:, None], moved, 0.0)
    anchor = scale * anchor  # (L, 3) in parent frame

    R_w, t_w = _compose(skel.levels, parents, R_root, pose.root_t, R_local, anchor)

    s_local = scale * skel.seg_start
    e_local = scale * (skel.seg_start + pose.lengths[:, None] * skel.seg_dir)
    start = t_w + _matvec(R_w, s_local)
    end = t_w + _matvec(R_w, e_local)
    radius = scale * skel.radius
    return Links(R_w, t_w, start, end, jnp.broadcast_to(radius, (L,)))


def capsules(skel: Skeleton, pose: Pose) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Shorthand: ``(start, end, radius)`` of every capsule."""
    links = forward_kinematics(skel, pose)
    return links.start, links.end, links.radius


def collision_pairs(skel: Skeleton, margin: float) -> CollisionPairs:
    """The capsule pairs of the collision term (:func:`jaxpose.objective.collision_cost`).

    Every pair of links but a link and its parent (they meet at the joint), each with
    ``rho = min(1, d_rest / (margin (r_i + r_j)))``, ``d_rest`` the distance of their
    axes in the rest pose (the skeleton's lengths, scale 1): pairs that overlap there
    keep the clearance they have.  The extra capsules of a robot file's link count as
    that link (:attr:`~jaxpose.skeleton.Skeleton.body`): no pair within one body, nor
    between a body and its parent's.  Works on a traced skeleton (``rho`` is computed).
    """
    L = skel.num_links
    body = skel.bodies
    par = [body[p] if p >= 0 else -1 for p in (skel.parents[b] for b in body)]  # each link's parent body
    ij = np.array([(i, j) for i in range(L) for j in range(i + 1, L)
                   if body[i] != body[j] and par[j] != body[i] and par[i] != body[j]], np.int32)
    i, j = ij.reshape(-1, 2).T
    links = forward_kinematics(skel, rest_pose(skel))
    d = segment_distance(links.start[i], links.end[i], links.start[j], links.end[j])
    clearance = margin * (links.radius[i] + links.radius[j])
    rho = jnp.where(clearance > 0, jnp.minimum(1.0, d / jnp.where(clearance > 0, clearance, 1.0)), 0.0)
    return CollisionPairs(i, j, rho)
