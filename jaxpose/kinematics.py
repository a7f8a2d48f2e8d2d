"""Forward kinematics: :class:`~jaxpose.skeleton.Pose` -> world frames and capsules.

Pure JAX, jit-compiled by the caller, vmappable over populations and batches.
Local joint rotations are computed for all links in one vectorised call, then
composed down the tree one depth level at a time (the level structure is static).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .skeleton import Pose, Skeleton, axis_angle_matrix, rpy_matrix


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
    anchor = scale * (skel.offset + skel.attach[:, None] * parent_tip)  # (L, 3) in parent frame

    R_w = jnp.zeros((L, 3, 3), R_local.dtype)
    t_w = jnp.zeros((L, 3), R_local.dtype)
    for level in skel.levels:
        idx = np.asarray(level)
        p = parents[idx]
        if np.all(p < 0):
            R_p = jnp.broadcast_to(R_root, (len(idx), 3, 3))
            t_p = jnp.broadcast_to(pose.root_t, (len(idx), 3))
        else:
            R_p, t_p = R_w[p], t_w[p]
        R_w = R_w.at[idx].set(R_p @ R_local[idx])
        t_w = t_w.at[idx].set(t_p + jnp.einsum("lij,lj->li", R_p, anchor[idx]))

    s_local = scale * skel.seg_start
    e_local = scale * (skel.seg_start + pose.lengths[:, None] * skel.seg_dir)
    start = t_w + jnp.einsum("lij,lj->li", R_w, s_local)
    end = t_w + jnp.einsum("lij,lj->li", R_w, e_local)
    radius = scale * skel.radius
    return Links(R_w, t_w, start, end, jnp.broadcast_to(radius, (L,)))


def capsules(skel: Skeleton, pose: Pose) -> tuple[jax.Array, jax.Array, jax.Array]:
    """Shorthand: ``(start, end, radius)`` of every capsule."""
    links = forward_kinematics(skel, pose)
    return links.start, links.end, links.radius
