"""The skeleton model: a tree of capsule links and its parameters.

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
flat genome ``g`` in ``[0, 1]^D`` (see :mod:`jaxpose.genome`).

Over 400 lines because :func:`build_skeleton` validates every field of every link
with its own error message, beside the fields it fills.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .errors import SkeletonError
from .geometry import rpy_matrix

if TYPE_CHECKING:
    from .genome import GenomeLayout

JOINT_DOF = {"ball": 3, "hinge": 1, "slide": 1, "fixed": 0}


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
    def layout(self) -> GenomeLayout:
        """Where each searched parameter sits in the genome (:func:`jaxpose.genome.genome_layout`)."""
        from .genome import genome_layout  # the genome module builds on this one

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
    _check_names(links, fail)
    order = _tree_order(links, fail)
    index = {l.name: i for i, l in enumerate(order)}
    for l in links:
        if l.body is not None and (l.body != l.parent or l.joint != "fixed"):
            fail(f"an extra capsule of link {l.body!r} must be a fixed child of it", l.name)
    lo_s, hi_s = _pair(scale_range, None, "scale range", fail)
    if not (lo_s > 0):
        fail(f"scale range must be positive, got {scale_range}")
    arrays = _link_arrays(order, require_geometry, fail)

    f32 = lambda a: jnp.asarray(a, jnp.float32)  # noqa: E731
    skel = Skeleton(
        **{k: f32(v) for k, v in arrays.items()}, scale_lo=f32(lo_s), scale_hi=f32(hi_s),
        name=str(name), link_names=tuple(l.name for l in order),
        parents=tuple(index[l.parent] if l.parent is not None else -1 for l in order),
        joint_types=tuple(l.joint for l in order),
        length_searched=tuple(bool(h > l) for l, h in zip(arrays["length_lo"], arrays["length_hi"])),
        body=tuple(index[l.body] if l.body is not None else i for i, l in enumerate(order)),
    )
    return dataclasses.replace(skel, orbit=_orbit_roots(skel))


def _check_names(links: list[LinkSpec], fail) -> None:
    """Every link has a unique non-empty name and an existing parent other than itself."""
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


def _tree_order(links: list[LinkSpec], fail) -> list[LinkSpec]:
    """The links in topological order (stable: file order among ready links); a cycle fails."""
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
    return order


def _link_arrays(order: list[LinkSpec], require_geometry: bool, fail) -> dict:
    """The numeric fields of :class:`Skeleton` (float64 NumPy arrays), every link checked in turn."""
    L = len(order)
    a = dict(offset=np.zeros((L, 3)), attach=np.zeros(L), rest_rotation=np.zeros((L, 3, 3)), axis=np.zeros((L, 3)),
             angle_lo=np.zeros((L, 3)), angle_hi=np.zeros((L, 3)), seg_start=np.zeros((L, 3)),
             seg_dir=np.zeros((L, 3)), length=np.zeros(L), length_lo=np.zeros(L), length_hi=np.zeros(L),
             radius=np.zeros(L))
    for i, l in enumerate(order):
        if not isinstance(l.joint, str) or l.joint not in JOINT_DOF:
            fail(f"unknown joint type {l.joint!r} (expected one of {', '.join(JOINT_DOF)})", l.name)
        a["offset"][i] = _vec3(l.offset, "offset", l.name, fail)
        a["attach"][i] = _attach(l, fail)
        if l.rest_matrix is not None:
            a["rest_rotation"][i] = np.asarray(l.rest_matrix, float).reshape(3, 3)
        else:
            a["rest_rotation"][i] = rpy_matrix(np.deg2rad(_vec3(l.rest, "rest", l.name, fail)))
        a["axis"][i] = _joint_axis(l, fail)
        dof = JOINT_DOF[l.joint]
        lo, hi = _joint_limits(l, fail)
        a["angle_lo"][i, :dof], a["angle_hi"][i, :dof] = lo, hi
        a["length"][i], a["length_lo"][i], a["length_hi"][i] = _length(l, require_geometry, fail)
        a["radius"][i] = _radius(l, fail)
        a["seg_start"][i] = _vec3(l.seg_start, "seg_start", l.name, fail)
        d = _vec3(l.seg_dir, "seg_dir", l.name, fail)
        n = np.linalg.norm(d)
        a["seg_dir"][i] = d / n if n > 0 else np.array([1.0, 0.0, 0.0])
    return a


def _attach(l: LinkSpec, fail) -> float:
    """``attach`` as a finite number (default: 1 for a link with a parent, 0 for a root)."""
    try:
        attach = float(l.attach if l.attach is not None else (1.0 if l.parent is not None else 0.0))
    except (TypeError, ValueError):
        fail(f"'attach' must be a number, got {l.attach!r}", l.name)
    if not np.isfinite(attach):
        fail(f"'attach' must be a finite number, got {l.attach!r}", l.name)
    return attach


def _joint_axis(l: LinkSpec, fail) -> np.ndarray:
    """The axis, normalised for the joints that use one (hinge, slide)."""
    ax = _vec3(l.axis, "axis", l.name, fail)
    if l.joint in ("hinge", "slide"):
        n = np.linalg.norm(ax)
        if not n > 0:
            fail(f"{l.joint} axis must be a non-zero vector", l.name)
        ax = ax / n
    return ax


def _joint_limits(l: LinkSpec, fail) -> tuple[np.ndarray, np.ndarray]:
    """Lower and upper limits ``(dof,)`` in radians (a slide: metres)."""
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
    return to_rad(lim[:, 0]), to_rad(lim[:, 1])


def _length(l: LinkSpec, require_geometry: bool, fail) -> tuple[float, float, float]:
    """``(length, lo, hi)``: the rest length clipped into its search range (a single value: fixed)."""
    try:
        length = float(l.length)
    except (TypeError, ValueError):
        fail(f"'length' must be a number, got {l.length!r}", l.name)
    if not np.isfinite(length) or length < 0 or (require_geometry and length <= 0):
        fail(f"length must be {'>' if require_geometry else '>='} 0, got {l.length}", l.name)
    if l.length_range is None:
        lo = hi = length
    else:
        lo, hi = _pair(l.length_range, l.name, "length_range", fail)
        if lo < 0 or lo > hi:
            fail(f"length_range must satisfy 0 <= lo <= hi, got {list(l.length_range)}", l.name)
        if lo == 0 and hi == 0 and length > 0:
            fail("length_range [0, 0] contradicts a positive length", l.name)
        length = np.clip(length, lo, hi)
    if require_geometry and not hi > 0:
        rng = f" with range {list(l.length_range)}" if l.length_range is not None else ""
        fail(f"length must be > 0, got {l.length}{rng}", l.name)
    return length, lo, hi


def _radius(l: LinkSpec, fail) -> float:
    try:
        radius = float(l.radius)
    except (TypeError, ValueError):
        fail(f"'radius' must be a number, got {l.radius!r}", l.name)
    if not np.isfinite(radius) or radius < 0:
        fail(f"radius must be >= 0, got {l.radius}", l.name)
    return radius


def _orbit_roots(skel: Skeleton) -> tuple[int, ...]:
    """Every link's symmetry orbit, named by its first link (:func:`jaxpose.symmetry.link_orbits`)."""
    from .symmetry import link_orbits  # it needs this module's Skeleton

    orbit = [0] * skel.num_links
    for o in link_orbits(skel):
        for i in o:
            orbit[i] = o[0]
    return tuple(orbit)


def _floats(v, n: int, link, fail, not_numbers: str, not_finite: str) -> np.ndarray:
    """``v`` as ``n`` finite float64 numbers, else ``fail`` with one of the two messages."""
    try:
        a = np.asarray(v, float).reshape(-1)
    except (TypeError, ValueError):
        fail(not_numbers, link)
    if a.shape != (n,) or not np.all(np.isfinite(a)):
        fail(not_finite, link)
    return a


def _vec3(v, what, link, fail):
    return _floats(v, 3, link, fail, f"{what!r} must be 3 numbers, got {v!r}",
                   f"{what!r} must be 3 finite numbers, got {v!r}")


def _pair(v, link, what, fail):
    a = _floats(v, 2, link, fail, f"{what} must be [lo, hi], got {v!r}",
                f"{what} must be two finite numbers [lo, hi], got {v!r}")
    if a[0] > a[1]:
        fail(f"inverted {what} {a.tolist()} (lo > hi)", link)
    return float(a[0]), float(a[1])
