"""The genome: the flat vector in ``[0, 1]^D`` that the search works on.

:class:`GenomeLayout` says where each searched parameter of a :class:`~jaxpose.skeleton.Skeleton`
sits in the genome, :class:`Bounds` gives every gene's physical range, and
:func:`decode`/:func:`encode` map a genome to a :class:`~jaxpose.skeleton.Pose` and back.
Fixed parameters (lengths whose range is a single value, the DOFs a joint does not
have) are not genes: :func:`decode` takes them from the rest pose.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .geometry import matrix_to_rpy, rpy_matrix
from .skeleton import JOINT_DOF, Pose, Skeleton, rest_pose

# Search range of the root orientation (roll, pitch, yaw), radians.
ROOT_ANGLE_LIMITS = np.array([[-np.pi, np.pi], [-np.pi / 2, np.pi / 2], [-np.pi, np.pi]])


@dataclass(frozen=True)
class GenomeLayout:
    """Where each searched parameter sits in the flat genome.

    The genome is ``[root_t (3), root_rpy (3), scale (1), then for every link in
    topological order: its joint values (ball 3, hinge 1, slide 1, fixed 0) followed by its
    length if the link's length range is not a single value]``.  Every gene lies in
    ``[0, 1]`` and maps linearly onto its parameter's range (the root's angles: onto a
    turn relative to the held orientation where :class:`Bounds` holds one).  ``target`` gives each
    gene's index in the flat parameter vector ``[root_t, root_rpy, scale,
    angles (L*3, row-major), lengths (L)]``.
    """

    names: tuple[str, ...]
    target: tuple[int, ...]
    link_of_gene: tuple[int, ...]  # -1 for the root genes
    num_links: int

    @property
    def size(self) -> int:
        return len(self.names)

    @property
    def num_params(self) -> int:
        return 7 + 4 * self.num_links

    def length_genes(self) -> tuple[np.ndarray, np.ndarray]:
        """``(genes, links)``: where the searched lengths sit in the genome, and their links."""
        genes = [k for k, n in enumerate(self.names) if n.endswith(".length")]
        return np.asarray(genes, np.int32), np.asarray([self.link_of_gene[k] for k in genes], np.int32)

    def gene_mask(self, links) -> np.ndarray:
        """Boolean mask over the genome of the genes belonging to ``links``."""
        links = set(links)
        return np.array([l in links for l in self.link_of_gene])


def genome_layout(skel: Skeleton) -> GenomeLayout:
    names, target, link_of = [], [], []
    for k, n in enumerate(["root_tx", "root_ty", "root_tz", "root_roll", "root_pitch", "root_yaw", "scale"]):
        names.append(n)
        target.append(k)
        link_of.append(-1)
    for i, (lname, jt) in enumerate(zip(skel.link_names, skel.joint_types)):
        for a in range(JOINT_DOF[jt]):
            names.append(f"{lname}.q{a}")
            target.append(7 + 3 * i + a)
            link_of.append(i)
        if skel.length_searched[i]:
            names.append(f"{lname}.length")
            target.append(7 + 3 * skel.num_links + i)
            link_of.append(i)
    return GenomeLayout(tuple(names), tuple(target), tuple(link_of), skel.num_links)


class Bounds(NamedTuple):
    """Physical range of every gene: gene 0 maps to ``lo``, gene 1 to ``hi``.

    Where ``turned`` (a traced boolean) is true, the root's roll, pitch and yaw genes are a
    turn *relative to* ``turn`` (a rotation matrix, composed as ``rpy_matrix(genes) @ turn``):
    a window about any orientation, of the same width in every direction, without the
    roll-pitch-yaw box's seams (docs/search.md, "Turn searches")."""

    lo: jax.Array  # (D,)
    hi: jax.Array  # (D,)
    turn: jax.Array | None = None  # (3, 3)
    turned: jax.Array | None = None  # () bool


def window(value, lo, hi, factor):
    """``(lo, hi)``: within ``factor`` of ``value`` either way, inside ``lo .. hi`` (never empty)."""
    w_lo = jnp.maximum(lo, value / factor)
    return w_lo, jnp.maximum(jnp.minimum(hi, value * factor), w_lo)


def held_bounds(bounds: Bounds, rpy, window, held) -> Bounds:
    """``bounds`` with the root's orientation held within ``window`` radians (about each axis)
    of the orientation ``rpy (3,)`` where ``held`` (traced), unchanged elsewhere."""
    w = jnp.where(held, window, 0.0)
    return Bounds(bounds.lo.at[3:6].set(jnp.where(held, -w, bounds.lo[3:6])),
                  bounds.hi.at[3:6].set(jnp.where(held, w, bounds.hi[3:6])),
                  rpy_matrix(jnp.asarray(rpy, jnp.float32)), jnp.asarray(held))


def root_rpy_values(bounds: Bounds, rpy, inverse: bool = False):
    """The root's orientation ``(..., 3)`` from its genes' values (``inverse``: the values from the orientation)."""
    if bounds.turn is None:
        return rpy
    T = bounds.turn.T if inverse else bounds.turn
    safe = jnp.where(bounds.turned, rpy, 0.0)  # no NaN gradients through the branch not taken
    return jnp.where(bounds.turned, matrix_to_rpy(rpy_matrix(safe) @ T), rpy)


def genome_bounds(skel: Skeleton, centre, extent) -> Bounds:
    """Gene ranges for a cloud centred at ``centre`` with radius ``extent`` (metres).

    The root may move anywhere within ``centre +- extent``; the scale and the joint
    and length ranges come from the skeleton.
    """
    layout = genome_layout(skel)
    centre = jnp.asarray(centre, jnp.float32)
    extent = jnp.asarray(extent, jnp.float32)
    L = skel.num_links
    full_lo = jnp.concatenate([
        centre - extent, jnp.asarray(ROOT_ANGLE_LIMITS[:, 0], jnp.float32), skel.scale_lo[None],
        skel.angle_lo.reshape(-1), skel.length_lo,
    ]).astype(jnp.float32)
    full_hi = jnp.concatenate([
        centre + extent, jnp.asarray(ROOT_ANGLE_LIMITS[:, 1], jnp.float32), skel.scale_hi[None],
        skel.angle_hi.reshape(-1), skel.length_hi,
    ]).astype(jnp.float32)
    assert full_lo.shape == (7 + 4 * L,)
    idx = np.asarray(layout.target, np.int32)
    return Bounds(full_lo[idx], full_hi[idx])


def _base_vector(skel: Skeleton) -> jax.Array:
    rest = rest_pose(skel)
    return pose_to_vector(rest)


def pose_to_vector(pose: Pose) -> jax.Array:
    return jnp.concatenate([
        pose.root_t, pose.root_rpy, jnp.reshape(pose.scale, (1,)), pose.angles.reshape(-1), pose.lengths
    ])


def vector_to_pose(vec: jax.Array, num_links: int) -> Pose:
    L = num_links
    return Pose(vec[0:3], vec[3:6], vec[6], vec[7 : 7 + 3 * L].reshape(L, 3), vec[7 + 3 * L : 7 + 4 * L])


def decode(skel: Skeleton, bounds: Bounds, genome: jax.Array) -> Pose:
    """Genome in ``[0, 1]^D`` (clipped) -> :class:`Pose`.  Differentiable; vmap for batches."""
    layout = genome_layout(skel)
    g = jnp.clip(genome, 0.0, 1.0)
    values = bounds.lo + g * (bounds.hi - bounds.lo)
    vec = _base_vector(skel).at[np.asarray(layout.target, np.int32)].set(values)
    vec = vec.at[3:6].set(root_rpy_values(bounds, vec[3:6]))  # root genes are always genes 3-5 (genome_layout)
    return vector_to_pose(vec, skel.num_links)


def encode(skel: Skeleton, bounds: Bounds, pose: Pose) -> jax.Array:
    """:class:`Pose` -> genome (values outside the ranges are clipped to ``[0, 1]``)."""
    layout = genome_layout(skel)
    vec = pose_to_vector(pose)
    vec = vec.at[3:6].set(root_rpy_values(bounds, vec[3:6], inverse=True))[np.asarray(layout.target, np.int32)]
    span = jnp.where(bounds.hi > bounds.lo, bounds.hi - bounds.lo, 1.0)
    return jnp.clip((vec - bounds.lo) / span, 0.0, 1.0)
