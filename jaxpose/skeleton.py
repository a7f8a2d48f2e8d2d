"""The skeleton model: a tree of capsule links, its parameters and its genome.

A :class:`Skeleton` is a pytree with a static topology (names, parent indices,
joint types, depth levels) and numeric leaves (offsets, rest rotations, limits,
lengths, radii).  Links are stored in topological order: ``parents[i] < i``.

Frames.  Every link ``i`` has a frame ``T_world_i``.  Its origin is the joint
anchor; its capsule runs from ``seg_start`` to ``seg_start + length * seg_dir``
(link frame, before the global scale).  For skeletons written in the native
format ``seg_start = 0`` and ``seg_dir = +x``: a link points along its own x axis.

    R_world_i = R_world_parent @ R_rest_i @ R_joint_i(q_i)
    t_world_i = t_world_parent + R_world_parent @ (scale * anchor_i)
    anchor_i  = offset_i + attach_i * (seg_start_p + length_p * seg_dir_p)

Links without a parent hang from the root frame (``R_root``, ``t_root``), whose
``anchor`` is just ``offset``.  The global ``scale`` multiplies every length,
offset and radius.

Joints.  ``ball``: three angles, ``R_joint = Rz(q2) @ Ry(q1) @ Rx(q0)`` (roll,
pitch, yaw about the rest frame's axes, the URDF ``rpy`` convention).  ``hinge``:
one angle about ``axis``.  ``slide`` (prismatic): one displacement ``q`` in metres
along ``axis`` (rest frame), ``R_joint = I`` and the anchor moves by
``R_rest_i @ axis_i * q`` (in the parent frame, times the global scale).
``fixed``: none.

Parameters (:class:`Pose`) are a pytree in physical units.  The search works on a
flat genome ``g`` in ``[0, 1]^D`` (see :class:`GenomeLayout`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .errors import SkeletonError
from .geometry import axis_angle_matrix  # noqa: F401  # imported by jaxpose/search until it moves
from .geometry import rpy_matrix

JOINT_DOF = {"ball": 3, "hinge": 1, "slide": 1, "fixed": 0}

# Search range of the root orientation (roll, pitch, yaw), radians.
ROOT_ANGLE_LIMITS = np.array([[-np.pi, np.pi], [-np.pi / 2, np.pi / 2], [-np.pi, np.pi]])


@dataclass(frozen=True)
class Skeleton:
    """A kinematic tree of capsule links (a JAX pytree; topology is static).

    Array fields have a leading link axis of size ``L`` in topological order.
    """

    # numeric leaves
    offset: jax.Array  # (L, 3) anchor offset in the parent frame, metres at scale 1
    attach: jax.Array  # (L,) fraction along the parent's segment added to the anchor
    rest_rotation: jax.Array  # (L, 3, 3) rest rotation R_rest
    axis: jax.Array  # (L, 3) hinge / slide axis (unit), unused for other joints
    angle_lo: jax.Array  # (L, 3) lower joint limits, radians (a slide: metres; unused DOFs 0)
    angle_hi: jax.Array  # (L, 3) upper joint limits
    seg_start: jax.Array  # (L, 3) capsule start in the link frame
    seg_dir: jax.Array  # (L, 3) unit capsule direction in the link frame
    length: jax.Array  # (L,) rest length (used when the length is not searched)
    length_lo: jax.Array  # (L,) length search range
    length_hi: jax.Array  # (L,)
    radius: jax.Array  # (L,) capsule radius at scale 1 (0: line segment)
    scale_lo: jax.Array  # () global scale search range
    scale_hi: jax.Array  # ()
    # static topology
    name: str = field(metadata=dict(static=True), default="skeleton")
    link_names: tuple[str, ...] = field(metadata=dict(static=True), default=())
    parents: tuple[int, ...] = field(metadata=dict(static=True), default=())
    joint_types: tuple[str, ...] = field(metadata=dict(static=True), default=())
    length_searched: tuple[bool, ...] = field(metadata=dict(static=True), default=())
    # every link's symmetry orbit, named by its first link (:func:`jaxpose.symmetry.link_orbits`;
    # set by build_skeleton; () = none known)
    orbit: tuple[int, ...] = field(metadata=dict(static=True), default=())
    # every link's rigid body, named by the link that carries it: itself, or for an extra capsule of a
    # robot file's link (a fixed child in its frame) that link; () = every link its own
    body: tuple[int, ...] = field(metadata=dict(static=True), default=())

    @property
    def num_links(self) -> int:
        return len(self.link_names)

    @property
    def levels(self) -> tuple[tuple[int, ...], ...]:
        """Link indices grouped by depth in the tree (roots first)."""
        return _levels(self.parents)

    @property
    def bodies(self) -> tuple[int, ...]:
        """Every link's rigid body (:attr:`body`; each link its own when not set)."""
        return self.body or tuple(range(self.num_links))

    @property
    def children(self) -> tuple[tuple[int, ...], ...]:
        return tuple(tuple(j for j, p in enumerate(self.parents) if p == i) for i in range(self.num_links))

    def subtree(self, i: int) -> tuple[int, ...]:
        """Indices of link ``i`` and all links below it."""
        out = [i]
        for j in range(i + 1, self.num_links):
            if self.parents[j] in out:
                out.append(j)
        return tuple(out)

    @property
    def layout(self) -> "GenomeLayout":
        return genome_layout(self)

    @property
    def num_dof(self) -> int:
        """Searched degrees of freedom: root pose (6) + scale (1) + joints + lengths."""
        return self.layout.size

    def index(self, name: str) -> int:
        try:
            return self.link_names.index(name)
        except ValueError:
            raise KeyError(f"skeleton {self.name!r} has no link {name!r}") from None


jax.tree_util.register_dataclass(
    Skeleton,
    data_fields=[f.name for f in dataclasses.fields(Skeleton) if not f.metadata.get("static")],
    meta_fields=[f.name for f in dataclasses.fields(Skeleton) if f.metadata.get("static")],
)


def _levels(parents: tuple[int, ...]) -> tuple[tuple[int, ...], ...]:
    depth = []
    for p in parents:
        depth.append(0 if p < 0 else depth[p] + 1)
    if not depth:
        return ()
    return tuple(tuple(i for i, d in enumerate(depth) if d == k) for k in range(max(depth) + 1))


class Pose(NamedTuple):
    """Skeleton parameters in physical units (a pytree; may carry batch axes)."""

    root_t: jax.Array  # (..., 3) root translation, metres
    root_rpy: jax.Array  # (..., 3) root orientation (roll, pitch, yaw), radians
    scale: jax.Array  # (...,) global scale
    angles: jax.Array  # (..., L, 3) joint angles, radians (a slide: metres; unused DOFs are 0)
    lengths: jax.Array  # (..., L) link lengths at scale 1, metres


def rest_pose(skel: Skeleton, root_t=(0.0, 0.0, 0.0), root_rpy=(0.0, 0.0, 0.0), scale=1.0) -> Pose:
    """The skeleton at rest: zero joint angles clipped into the limits, rest lengths."""
    zero = jnp.clip(jnp.zeros_like(skel.angle_lo), skel.angle_lo, skel.angle_hi)
    return Pose(
        jnp.asarray(root_t, jnp.float32),
        jnp.asarray(root_rpy, jnp.float32),
        jnp.asarray(scale, jnp.float32),
        zero,
        jnp.asarray(skel.length, jnp.float32),
    )


# --------------------------------------------------------------------------- genome


@dataclass(frozen=True)
class GenomeLayout:
    """Where each searched parameter sits in the flat genome.

    The genome is ``[root_t (3), root_rpy (3), scale (1), then for every link in
    topological order: its joint values (ball 3, hinge 1, slide 1, fixed 0) followed by its
    length if the link's length range is not a single value]``.  Every gene lies in
    ``[0, 1]`` and maps linearly onto its parameter's range.  ``target`` gives each
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
    """Physical range of every gene: gene 0 maps to ``lo``, gene 1 to ``hi``."""

    lo: jax.Array  # (D,)
    hi: jax.Array  # (D,)


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
    return vector_to_pose(vec, skel.num_links)


def encode(skel: Skeleton, bounds: Bounds, pose: Pose) -> jax.Array:
    """:class:`Pose` -> genome (values outside the ranges are clipped to ``[0, 1]``)."""
    layout = genome_layout(skel)
    vec = pose_to_vector(pose)[np.asarray(layout.target, np.int32)]
    span = jnp.where(bounds.hi > bounds.lo, bounds.hi - bounds.lo, 1.0)
    return jnp.clip((vec - bounds.lo) / span, 0.0, 1.0)


# --------------------------------------------------------------------------- construction


@dataclass
class LinkSpec:
    """A link as written in a file, before validation (physical units, degrees for angles)."""

    name: str
    parent: str | None = None
    joint: str = "ball"
    offset: tuple = (0.0, 0.0, 0.0)
    attach: float | None = None  # default: 1 for links with a parent, 0 otherwise
    rest: tuple = (0.0, 0.0, 0.0)  # rest rotation rpy, degrees
    rest_matrix: np.ndarray | None = None  # overrides ``rest`` (importers)
    axis: tuple = (0.0, 0.0, 1.0)
    limits: list | None = None  # degrees: ball [[lo,hi]]*3, hinge [[lo,hi]]; slide: metres [[lo,hi]]
    length: float = 0.1
    length_range: tuple | None = None  # default: fixed at ``length``
    radius: float = 0.0
    seg_start: tuple = (0.0, 0.0, 0.0)
    seg_dir: tuple = (1.0, 0.0, 0.0)
    body: str | None = None  # an extra capsule of link ``body`` (its parent, a fixed joint in its frame)


def build_skeleton(
    name: str,
    links: list[LinkSpec],
    scale_range=(0.5, 2.0),
    source: str = "<skeleton>",
    require_geometry: bool = True,
) -> Skeleton:
    """Validate link specs and build a :class:`Skeleton` (links are sorted topologically).

    With ``require_geometry`` (native files) every link needs a positive length;
    importers of robot files pass ``False`` so that bodies without geometry
    (zero length and zero radius) still take part in the kinematics.

    Raises :class:`SkeletonError` naming ``source``, the link and the problem.
    """

    def fail(msg, link=None):
        where = f"{source}: link {link!r}: " if link is not None else f"{source}: "
        raise SkeletonError(where + msg)

    if not links:
        fail("the skeleton has no links")
    seen = set()
    for l in links:
        if not isinstance(l.name, str) or not l.name:
            fail("every link needs a non-empty string 'name'")
        if l.name in seen:
            fail("duplicate link name", l.name)
        seen.add(l.name)
    by_name = {l.name: l for l in links}
    for l in links:
        if l.parent is not None and l.parent not in by_name:
            fail(f"unknown parent {l.parent!r}", l.name)
        if l.parent == l.name:
            fail("a link cannot be its own parent", l.name)
    # topological order (stable: file order among ready links), detecting cycles
    order, placed = [], set()
    pending = list(links)
    while pending:
        ready = [l for l in pending if l.parent is None or l.parent in placed]
        if not ready:
            # name a link on the cycle (pending[0] may merely hang below one)
            parent_of = {l.name: l.parent for l in pending}
            walk, name = [], pending[0].name
            while name not in walk:
                walk.append(name)
                name = parent_of[name]
            cycle = walk[walk.index(name):]
            fail(f"the parent links form a cycle ({' -> '.join(cycle + [name])})", name)
        for l in ready:
            order.append(l)
            placed.add(l.name)
        pending = [l for l in pending if l.name not in placed]
    index = {l.name: i for i, l in enumerate(order)}
    for l in links:
        if l.body is not None and (l.body != l.parent or l.joint != "fixed"):
            fail(f"an extra capsule of link {l.body!r} must be a fixed child of it", l.name)

    lo_s, hi_s = _pair(scale_range, source, None, "scale range", fail)
    if not (lo_s > 0):
        fail(f"scale range must be positive, got {scale_range}")

    L = len(order)
    offset = np.zeros((L, 3))
    attach = np.zeros(L)
    rest = np.zeros((L, 3, 3))
    axis = np.zeros((L, 3))
    alo = np.zeros((L, 3))
    ahi = np.zeros((L, 3))
    seg_start = np.zeros((L, 3))
    seg_dir = np.zeros((L, 3))
    length = np.zeros(L)
    llo = np.zeros(L)
    lhi = np.zeros(L)
    radius = np.zeros(L)
    for i, l in enumerate(order):
        if not isinstance(l.joint, str) or l.joint not in JOINT_DOF:
            fail(f"unknown joint type {l.joint!r} (expected one of {', '.join(JOINT_DOF)})", l.name)
        offset[i] = _vec3(l.offset, "offset", l.name, fail)
        try:
            attach[i] = float(l.attach if l.attach is not None else (1.0 if l.parent is not None else 0.0))
        except (TypeError, ValueError):
            fail(f"'attach' must be a number, got {l.attach!r}", l.name)
        if not np.isfinite(attach[i]):
            fail(f"'attach' must be a finite number, got {l.attach!r}", l.name)
        if l.rest_matrix is not None:
            rest[i] = np.asarray(l.rest_matrix, float).reshape(3, 3)
        else:
            rest[i] = rpy_matrix(np.deg2rad(_vec3(l.rest, "rest", l.name, fail)))
        ax = _vec3(l.axis, "axis", l.name, fail)
        if l.joint in ("hinge", "slide"):
            n = np.linalg.norm(ax)
            if not n > 0:
                fail(f"{l.joint} axis must be a non-zero vector", l.name)
            ax = ax / n
        axis[i] = ax
        dof = JOINT_DOF[l.joint]
        unit = "metres" if l.joint == "slide" else "degrees"
        lim = l.limits
        if lim is None:
            if l.joint == "slide":
                fail("a slide joint needs 'limits' (one [lo, hi] pair, metres)", l.name)
            lim = [[-180.0, 180.0]] * dof
        try:
            lim = np.asarray(lim, float).reshape(-1, 2) if dof else np.zeros((0, 2))
        except (TypeError, ValueError):
            fail(f"'limits' must be {dof} pair(s) of numbers ({unit})", l.name)
        if lim.shape[0] != dof:
            fail(f"'limits' must have {dof} [lo, hi] pair(s) for a {l.joint} joint, got {lim.shape[0]}", l.name)
        if not np.all(np.isfinite(lim)):
            fail("joint limits must be finite numbers", l.name)
        if np.any(lim[:, 0] > lim[:, 1]):
            fail(f"inverted joint limits {lim.tolist()} (lower > upper)", l.name)
        to_rad = (lambda v: v) if l.joint == "slide" else np.deg2rad
        alo[i, :dof] = to_rad(lim[:, 0])
        ahi[i, :dof] = to_rad(lim[:, 1])
        try:
            length[i] = float(l.length)
        except (TypeError, ValueError):
            fail(f"'length' must be a number, got {l.length!r}", l.name)
        if not np.isfinite(length[i]) or length[i] < 0 or (require_geometry and length[i] <= 0):
            fail(f"length must be {'>' if require_geometry else '>='} 0, got {l.length}", l.name)
        if l.length_range is None:
            llo[i] = lhi[i] = length[i]
        else:
            llo[i], lhi[i] = _pair(l.length_range, source, l.name, "length_range", fail)
            if llo[i] < 0 or llo[i] > lhi[i]:
                fail(f"length_range must satisfy 0 <= lo <= hi, got {list(l.length_range)}", l.name)
            if llo[i] == 0 and lhi[i] == 0 and length[i] > 0:
                fail("length_range [0, 0] contradicts a positive length", l.name)
            length[i] = np.clip(length[i], llo[i], lhi[i])
        if require_geometry and not lhi[i] > 0:
            rng = f" with range {list(l.length_range)}" if l.length_range is not None else ""
            fail(f"length must be > 0, got {l.length}{rng}", l.name)
        try:
            radius[i] = float(l.radius)
        except (TypeError, ValueError):
            fail(f"'radius' must be a number, got {l.radius!r}", l.name)
        if not np.isfinite(radius[i]) or radius[i] < 0:
            fail(f"radius must be >= 0, got {l.radius}", l.name)
        seg_start[i] = _vec3(l.seg_start, "seg_start", l.name, fail)
        d = _vec3(l.seg_dir, "seg_dir", l.name, fail)
        n = np.linalg.norm(d)
        seg_dir[i] = d / n if n > 0 else np.array([1.0, 0.0, 0.0])

    f32 = lambda a: jnp.asarray(a, jnp.float32)  # noqa: E731
    skel = Skeleton(
        offset=f32(offset), attach=f32(attach), rest_rotation=f32(rest), axis=f32(axis),
        angle_lo=f32(alo), angle_hi=f32(ahi), seg_start=f32(seg_start), seg_dir=f32(seg_dir),
        length=f32(length), length_lo=f32(llo), length_hi=f32(lhi), radius=f32(radius),
        scale_lo=f32(lo_s), scale_hi=f32(hi_s),
        name=str(name), link_names=tuple(l.name for l in order),
        parents=tuple(index[l.parent] if l.parent is not None else -1 for l in order),
        joint_types=tuple(l.joint for l in order),
        length_searched=tuple(bool(h > l) for l, h in zip(llo, lhi)),
        body=tuple(index[l.body] if l.body is not None else i for i, l in enumerate(order)),
    )
    from .symmetry import link_orbits  # it needs this module's Skeleton

    orbit = [0] * len(order)
    for o in link_orbits(skel):
        for i in o:
            orbit[i] = o[0]
    return dataclasses.replace(skel, orbit=tuple(orbit))


def _vec3(v, what, link, fail):
    try:
        a = np.asarray(v, float).reshape(-1)
    except (TypeError, ValueError):
        fail(f"{what!r} must be 3 numbers, got {v!r}", link)
    if a.shape != (3,) or not np.all(np.isfinite(a)):
        fail(f"{what!r} must be 3 finite numbers, got {v!r}", link)
    return a


def _pair(v, source, link, what, fail):
    try:
        a = np.asarray(v, float).reshape(-1)
    except (TypeError, ValueError):
        fail(f"{what} must be [lo, hi], got {v!r}", link)
    if a.shape != (2,) or not np.all(np.isfinite(a)):
        fail(f"{what} must be two finite numbers [lo, hi], got {v!r}", link)
    if a[0] > a[1]:
        fail(f"inverted {what} {a.tolist()} (lo > hi)", link)
    return float(a[0]), float(a[1])
