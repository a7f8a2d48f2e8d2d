"""URDF robot files -> :class:`~jaxpose.skeleton.Skeleton`, and the capsule approximation of geometry.

Mapping.  Every URDF ``<link>`` becomes a jaxpose link of the same name; every
``<joint>`` sets the frame of its child link in its parent link's frame:

==============================  ==========================================================
URDF                            jaxpose
==============================  ==========================================================
``<link name>``                 link ``name`` (the root link hangs from the searched root)
joint ``<origin xyz rpy>``      ``offset = xyz``, ``rest_matrix = Rz(y) Ry(p) Rx(r)``, ``attach = 0``
``revolute``                    ``hinge`` about ``<axis xyz>`` (joint frame), ``<limit lower upper>``
``continuous``                  ``hinge``, limits [-180, 180] degrees
``prismatic``                   ``slide`` along ``<axis xyz>``, ``<limit lower upper>`` (metres)
``spherical`` (PyBullet)        ``ball``, limits [-180, 180] degrees on each angle
``fixed``                       ``fixed`` (a zero-DOF link)
``floating``, ``planar``        rejected (the root pose is always searched anyway)
``<mimic>``                     ignored: the joint is searched independently
==============================  ==========================================================

The frames are those of the URDF: with ``attach = 0`` a link's anchor is just its
joint origin, so ``forward_kinematics(...).origin`` is the URDF link origin.

Geometry.  ``<collision>`` elements are used when a link has any, otherwise its
``<visual>`` elements.  Each becomes one capsule in the link frame (see
:func:`link_capsule`, shared with the MJCF importer):

* ``sphere``: a zero-length capsule of the same radius;
* ``cylinder``: the capsule along its axis with the same radius and segment length
  (it encloses the cylinder; the caps stick out by one radius);
* ``capsule`` (a common extension): exact;
* ``box``: a capsule along its longest axis with the half-diagonal of the two other
  sides as radius and the full long side as segment (it encloses the box);
* ``mesh``: a Wavefront ``.obj`` or an STL (binary or ASCII) file, found beside the
  URDF (a relative path, ``file://``, or ``package://PKG/...`` looked up as ``PKG/...``
  and as ``...`` in the URDF's folder and its parents), is read: its vertices, scaled
  by ``scale`` and placed by the geometry's origin, are enclosed like the other
  shapes; a link made of meshes only (with 16 vertices or more) then gets the capsule
  fitted to those vertices (:func:`surface_capsule`), not the enclosing one, which
  is much fatter than most meshes.  A mesh that cannot be found or is of another format (e.g. COLLADA
  ``.dae``) is stood in for by a ball of radius :data:`DEFAULT_MESH_RADIUS` times the
  largest ``scale`` factor at the geometry's origin; give the link a ``<collision>``
  primitive for a better fit.  A mesh file that is found but unreadable is an error.

That is the one-capsule model (``max_capsules=1``), where a link with several
geometries gets one capsule enclosing all of them.  By default a link gets up to
:data:`MAX_CAPSULES` capsules (:func:`link_capsules`): one per geometry, flat boxes
and disks cut into slabs, the extra capsules as fixed child links
``<link>#capsule2``, ... in the link's frame.  A link with no geometry keeps
length 0 and radius 0 and only takes part in the kinematics.  Lengths
and radii are fixed unless ``search_lengths=True``, which searches every non-zero
capsule length within ``+-LENGTH_SEARCH_FRACTION`` (the capsule grows from its
start point; child joints do not move).

Why the standard library parser.  URDF is plain XML and the importer needs only
its stable core (``link``, ``joint``, ``origin``, ``axis``, ``limit``,
``collision``/``visual`` geometry); ``xml.etree.ElementTree`` reads that subset in
a few lines, so no extra dependency (``urdfdom``, ``yourdfpy``, ...) is needed and
error messages stay ours.  ROS ``package://`` paths and xacro macros are not
resolved: expand xacro files to plain URDF first.
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET

import numpy as np

from ..errors import SkeletonError
from ..geometry import point_segment_distance, rpy_matrix
from ..skeleton import LinkSpec, Skeleton, build_skeleton

DEFAULT_MESH_RADIUS = 0.05  # metres: stand-in ball for a mesh that is not read
LENGTH_SEARCH_FRACTION = 0.3  # search_lengths: lengths vary within +-30 %
_EPS = 1e-12


# --------------------------------------------------------------------------- geometry -> capsule


class Shape:
    """Geometry as balls whose convex hull encloses it, plus preferred capsule axes.

    ``centres`` ``(n, 3)`` and ``radii`` ``(n,)`` are in the link frame; ``axes``
    ``(k, 3)`` are candidate capsule directions (a capsule's own axis, a box's
    axes, longest first); ``surface``: points on the geometry's surface (a mesh's
    vertices), to which :func:`link_capsule` fits the capsule, or ``None``.
    """

    def __init__(self, centres, radii, axes=(), surface=None, split=None, sample=None):
        self.centres = np.asarray(centres, float).reshape(-1, 3)
        self.radii = np.broadcast_to(np.asarray(radii, float), (len(self.centres),)).copy()
        self.axes = np.asarray(axes, float).reshape(-1, 3)
        self.surface = None if surface is None else np.asarray(surface, float).reshape(-1, 3)
        # boxes and cylinders: ``split(k) -> [Shape] * k``, slabs each one capsule; ``sample(n) -> (points
        # (n, 3) spread evenly over the surface, its area)``, to judge which capsules follow it closer
        self.split = split
        self.sample = sample


def sphere_shape(pos, radius) -> Shape:
    return Shape([pos], [radius])


def capsule_shape(pos, R, radius, half_length) -> Shape:
    """Capsule (or enclosing capsule of a cylinder) along the local z axis of frame ``(R, pos)``."""
    z = np.asarray(R, float)[:, 2]
    pos = np.asarray(pos, float)
    return Shape([pos - half_length * z, pos + half_length * z], [radius, radius], [z])


def cylinder_shape(pos, R, radius, half_length) -> Shape:
    """A cylinder along the local z axis of frame ``(R, pos)``: enclosed by the capsule along its axis
    (:func:`capsule_shape`), or cut into slabs across its axis (:func:`_slabs`)."""
    shape = capsule_shape(pos, R, radius, half_length)
    if not radius > _EPS:  # a line: nothing to cut
        return shape
    R, pos = np.asarray(R, float), np.asarray(pos, float)
    shape.split = lambda k: _slabs(pos, R[:, 0], R[:, 1], R[:, 2], radius, radius, half_length, k, disk=True)

    def sample(n):
        rng = np.random.default_rng(0)
        faces, side = 2 * np.pi * radius**2, 4 * np.pi * radius * half_length
        on_face = rng.uniform(size=n) < faces / max(faces + side, _EPS)
        rho, phi = radius * np.sqrt(rng.uniform(size=n)), rng.uniform(0, 2 * np.pi, n)
        rho = np.where(on_face, rho, radius)
        z = np.where(on_face, np.where(rng.uniform(size=n) < 0.5, 1.0, -1.0), rng.uniform(-1, 1, n)) * half_length
        return pos + np.stack([rho * np.cos(phi), rho * np.sin(phi), z], 1) @ R.T, faces + side

    shape.sample = sample
    return shape


def box_shape(pos, R, half_sizes) -> Shape:
    """The eight corners of a box (half sizes along the local axes of frame ``(R, pos)``), which can be
    cut into slabs across its middle side (:func:`_slabs`)."""
    R, pos, h = np.asarray(R, float), np.asarray(pos, float), np.abs(np.asarray(half_sizes, float))
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
    corners = pos + (signs * h) @ R.T
    order = np.argsort(-h, kind="stable")
    (a, b, c), (ea, eb, ec) = h[order], R[:, order].T

    def sample(n):
        rng = np.random.default_rng(0)
        areas = np.array([h[1] * h[2], h[0] * h[2], h[0] * h[1]] * 2)
        face = rng.choice(6, n, p=areas / max(areas.sum(), _EPS))
        u = rng.uniform(-1, 1, (n, 3))
        u[np.arange(n), face % 3] = np.where(face < 3, 1.0, -1.0)
        return pos + (u * h) @ R.T, 4.0 * float(areas.sum())

    if not b > _EPS:  # a line or a point: nothing to cut, no surface to sample
        return Shape(corners, 0.0, R[:, order].T)
    return Shape(corners, 0.0, R[:, order].T, split=lambda k: _slabs(pos, ea, eb, ec, a, b, c, k), sample=sample)


def _slabs(pos, ea, eb, ec, a, b, c, k: int, disk: bool = False) -> list[Shape]:
    """``k`` slabs side by side across ``eb`` that make up the box of half sizes ``a, b, c`` along
    ``ea, eb, ec`` centred at ``pos`` or, ``disk``, the disk of radius ``a = b`` in the ``ea, eb`` plane,
    ``c`` thick (each slab as long as the disk's chord through its middle, so that its capsule ends
    on the rim).  Each slab is its own capsule (:func:`slab_capsule`)."""
    edges = np.linspace(-b, b, k + 1)
    out = []
    for lo, hi in zip(edges[:-1], edges[1:]):
        mid = 0.5 * (lo + hi)
        half = float(np.sqrt(max(a * a - mid * mid, 0.0))) if disk else a
        out.append(slab_capsule(pos + mid * eb, (ea, eb, ec), (half, 0.5 * (hi - lo), c)))
    return out


def slab_capsule(pos, axes, half_sizes) -> Shape:
    """The capsule standing in for one slab (a box of ``half_sizes`` along ``axes`` centred at ``pos``):
    along its longest side, with the radius of a disk as large as its cross-section
    (``sqrt(4 h2 h3 / pi)``) and the segment ending one radius inside its end faces.  Not an
    enclosing capsule: one whose caps stick out past the slab's ends by its radius (as an enclosing
    capsule's must) would put surface where there is none, beside the next slab."""
    h = np.abs(np.asarray(half_sizes, float))
    order = np.argsort(-h, kind="stable")
    h1, h2, h3 = h[order]
    e = [np.asarray(axes[i], float) for i in order]
    r = min(float(np.sqrt(4.0 * h2 * h3 / np.pi)), h1)
    return capsule_shape(pos, np.stack([e[1], e[2], e[0]], 1), r, h1 - r)


def ellipsoid_shape(pos, R, radii) -> Shape:
    """Enclosing capsule of an ellipsoid: along its longest axis, radius the larger other radius.

    With ``a`` the longest radius and ``r`` the larger of the two others, the balls of
    radius ``r`` at ``+-(a - r)`` span a capsule that contains the ellipsoid and
    touches it at both tips.
    """
    R, pos, rad = np.asarray(R, float), np.asarray(pos, float), np.abs(np.asarray(radii, float))
    k = int(np.argmax(rad))
    r = float(np.max(np.delete(rad, k)))
    d = R[:, k]
    return Shape([pos - (rad[k] - r) * d, pos + (rad[k] - r) * d], [r, r], [d])


def points_shape(points) -> Shape:
    """A mesh's vertices: zero-radius balls for the enclosing capsule, and its surface points."""
    return Shape(points, 0.0, surface=points)


def _perp_basis(d):
    a = np.eye(3)[int(np.argmin(np.abs(d)))]
    e1 = np.cross(d, a)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(d, e1)


def enclosing_capsule(shapes: list[Shape]):
    """One capsule enclosing every shape: ``(seg_start, seg_dir, length, radius)``.

    Each shape is a set of balls whose convex hull encloses the geometry, and a
    capsule is convex, so a capsule holding every ball holds the geometry.  For a
    candidate axis ``d`` the capsule's line passes through the centre of the balls'
    bounding rectangle across ``d``; its radius is the largest (distance to the line
    + ball radius), and its segment is the shortest one that keeps every ball inside.
    Candidates are the shapes' own axes (a capsule's axis, a box's axes), the
    principal axes of the ball centres and the frame axes; the capsule of least
    volume wins (ties go to the earlier candidate, so one capsule is reproduced
    exactly and a box lies along its longest side).  No shape: a zero capsule.
    """
    shapes = [s for s in shapes if len(s.centres)]
    if not shapes:
        return np.zeros(3), np.array([1.0, 0.0, 0.0]), 0.0, 0.0
    c = np.concatenate([s.centres for s in shapes])
    r = np.concatenate([s.radii for s in shapes])
    cands = [a for s in shapes for a in s.axes]
    if len(c) >= 2:
        dev = c - c.mean(0)
        w, v = np.linalg.eigh(dev.T @ dev)
        if w[-1] > _EPS:
            cands += [v[:, k] for k in np.argsort(-w)]
    cands += list(np.eye(3))
    best = None
    for d in cands:
        n = np.linalg.norm(d)
        if not n > _EPS:
            continue
        d = d / n
        e1, e2 = _perp_basis(d)
        t, u, v = c @ d, c @ e1, c @ e2
        uc = 0.5 * (np.max(u + r) + np.min(u - r))
        vc = 0.5 * (np.max(v + r) + np.min(v - r))
        rho = np.hypot(u - uc, v - vc)
        R = float(np.max(rho + r))
        slack = np.sqrt(np.maximum((R - r) ** 2 - rho**2, 0.0))
        t1, t0 = float(np.max(t - slack)), float(np.min(t + slack))
        if t1 < t0:  # every ball fits in one ball of radius R: a zero-length capsule
            t0 = t1 = 0.5 * (t0 + t1)
        length = t1 - t0
        volume = np.pi * R * R * length + 4.0 / 3.0 * np.pi * R**3
        if best is None or volume < best[0] * (1 - 1e-9) - 1e-15:
            best = (volume, uc * e1 + vc * e2 + t0 * d, d, length, R)
    _, start, d, length, R = best
    if length <= 1e-12:
        length = 0.0
    return start, d, length, R


MIN_SURFACE_POINTS = 16  # a mesh with fewer vertices keeps its enclosing capsule
MAX_SURFACE_POINTS = 3000  # vertices a capsule is fitted to (evenly spaced through the mesh's list)


def surface_capsule(points, start, d, length, radius):
    """The capsule whose surface passes closest to ``points`` (a mesh's vertices), starting from the
    enclosing capsule ``(start, d, length, radius)``: robust least squares (``soft_l1``) on each point's
    distance to the capsule's surface.  Returns ``(seg_start, seg_dir, length, radius)``; the enclosing
    capsule when the fit degenerates (a radius outside 0.1 .. 1.05 of the enclosing one, or a longer
    segment than the enclosing capsule's whole extent)."""
    from scipy.optimize import least_squares

    P = np.asarray(points, float)
    if len(P) > MAX_SURFACE_POINTS:
        P = P[np.linspace(0, len(P) - 1, MAX_SURFACE_POINTS).astype(int)]
    a0, b0 = start, start + length * d
    x0 = np.concatenate([a0, b0, [radius]])
    # the ends stay within a radius of the enclosing segment's box: points on a flat end face are as
    # close to a segment running on through it, so without bounds the segment drifts out of the shape
    lo = np.concatenate([np.minimum(a0, b0) - radius] * 2 + [[0.0]])
    hi = np.concatenate([np.maximum(a0, b0) + radius] * 2 + [[1.05 * radius]])
    sol = least_squares(lambda x: point_segment_distance(P, x[:3], x[3:6], xp=np) - x[6], x0, bounds=(lo, hi),
                        loss="soft_l1", f_scale=max(0.1 * radius, 1e-4), max_nfev=300)
    a, b, r = sol.x[:3], sol.x[3:6], float(sol.x[6])
    L = float(np.linalg.norm(b - a))
    if not (sol.success and 0.1 * radius < r <= 1.05 * radius and L <= length + 2 * radius):
        return start, d, length, radius
    return a, ((b - a) / L if L > 1e-9 else d), (L if L > 1e-9 else 0.0), r


def link_capsule(shapes: list[Shape]):
    """A link's capsule ``(seg_start, seg_dir, length, radius)``: the one enclosing every shape
    (:func:`enclosing_capsule`), except for a link made of meshes only, whose capsule is fitted to the
    meshes' surface (:func:`surface_capsule`).  An enclosing capsule is exact for a capsule and tight
    for a cylinder, but much fatter than most meshes (a robot arm's rounded links), and the objective
    scores the distance to the capsule's surface from outside and inside alike: MuJoCo renders of two
    mesh arms, 4 views each, symmetric PCP 59% -> 84% and 36% -> 66%, median MPJPE 31 -> 12 and 57 -> 18 mm
    (docs/experiments.md)."""
    start, d, length, radius = enclosing_capsule(shapes)
    shapes = [s for s in shapes if len(s.centres)]
    if not shapes or any(s.surface is None for s in shapes) or radius <= 0:
        return start, d, length, radius
    surface = np.concatenate([s.surface for s in shapes])
    if len(surface) < MIN_SURFACE_POINTS:
        return start, d, length, radius
    return surface_capsule(surface, start, d, length, radius)


def capsule_volume(radius: float, length: float) -> float:
    return float(np.pi * radius * radius * length + 4.0 / 3.0 * np.pi * radius**3)


SURFACE_SAMPLES = 512  # points on a box's or cylinder's surface that judge its capsules
SPLIT_GAIN = 0.4  # a further slab must bring the shape's surface this much closer (relative)


def surface_gap(points, caps) -> float:
    """Mean distance of ``points`` to the nearest capsule surface, inside or out (as the data term
    measures it), of capsules ``(seg_start, seg_dir, length, radius)``."""
    P = np.asarray(points, float)
    d = [np.abs(point_segment_distance(P, np.asarray(a, float), np.asarray(a, float) + length * np.asarray(u, float), xp=np)
               - r)
         for a, u, length, r in caps]
    return float(np.mean(np.min(d, axis=0)))


def link_capsules(shapes: list[Shape], max_capsules: int = 1) -> list[tuple]:
    """Up to ``max_capsules`` capsules ``(seg_start, seg_dir, length, radius)`` for one link, the
    largest first.  One: :func:`link_capsule` of all the shapes.  More: one capsule per shape
    (:func:`link_capsule` of each: a mesh's is fitted to its surface; a box or cylinder gets the
    enclosing capsule or, when its surface lies closer to it, the capsule of its cross-section,
    :func:`slab_capsule`), and what the budget leaves cuts boxes and cylinders into slabs
    (:attr:`Shape.split`), one slab more at a time where it brings a shape's surface closest to its
    capsules (:func:`surface_gap` times the shape's area), as long as it brings it at least
    :data:`SPLIT_GAIN` closer.  A link with more shapes than
    capsules keeps the largest ``max_capsules - 1`` apart and encloses the rest in one capsule.  A
    link without geometry: one zero capsule."""
    shapes = [s for s in shapes if len(s.centres)]
    if max_capsules <= 1 or not shapes:
        return [link_capsule(shapes)]
    if len(shapes) > max_capsules:
        size = [capsule_volume(c[3], c[2]) for c in map(lambda s: enclosing_capsule([s]), shapes)]
        order = np.argsort(size, kind="stable")[::-1]
        groups = [[shapes[i]] for i in order[: max_capsules - 1]] + [[shapes[i] for i in order[max_capsules - 1:]]]
        return _largest_first([link_capsule(g) for g in groups])
    caps = {}  # (shape, pieces) -> capsules
    error = {}  # (shape, pieces) -> surface gap x area

    def pieces(i, n):
        if (i, n) not in caps:
            s = shapes[i]
            options = [[link_capsule([p]) for p in s.split(n)]] if n > 1 else [[link_capsule([s])]]
            if n == 1 and s.split is not None:  # one slab: the capsule of its cross-section's disk
                options.append([link_capsule(s.split(1))])
            if s.sample is not None:
                points, area = s.sample(SURFACE_SAMPLES)
                gaps = [surface_gap(points, c) * area for c in options]
                k = int(np.argmin(gaps))  # ties: the enclosing capsule
                options, error[i, n] = [options[k]], gaps[k]
            caps[i, n] = options[0]
        return caps[i, n]

    counts = [1] * len(shapes)
    while sum(counts) < max_capsules:
        gain = np.zeros(len(shapes))
        for i, (s, n) in enumerate(zip(shapes, counts)):
            if s.split is not None and s.sample is not None:
                pieces(i, n), pieces(i, n + 1)
                if error[i, n + 1] < (1 - SPLIT_GAIN) * error[i, n]:
                    gain[i] = error[i, n] - error[i, n + 1]
        i = int(np.argmax(gain))
        if not gain[i] > 0:
            break
        counts[i] += 1
    return _largest_first([c for i, n in enumerate(counts) for c in pieces(i, n)])


def _largest_first(caps: list[tuple]) -> list[tuple]:
    return sorted(caps, key=lambda c: -capsule_volume(c[3], c[2]))  # stable: ties keep their order


EXTRA_CAPSULE = "#capsule"  # extra capsules of link "arm" are the fixed links "arm#capsule2", ...
# capsules per link at most, by default (robot files): see link_capsules and docs/experiments.md
MAX_CAPSULES = 4


def check_max_capsules(max_capsules, source: str) -> int:
    """``max_capsules`` as an int, or one :class:`SkeletonError` naming ``source`` unless it is a
    whole number >= 1."""
    if isinstance(max_capsules, bool) or not isinstance(max_capsules, (int, np.integer)) or max_capsules < 1:
        raise SkeletonError(f"{source}: max_capsules must be a whole number >= 1, got {max_capsules!r}")
    return int(max_capsules)


def capsules_named(names) -> int:
    """The most capsules a link has in a list of link names (a link and its ``EXTRA_CAPSULE`` links):
    the ``max_capsules`` that loads a robot file with these names back (1 when there are none)."""
    counts = [name.rsplit(EXTRA_CAPSULE, 1)[1] for name in names if EXTRA_CAPSULE in name]
    return max([int(k) for k in counts if k.isdigit()] + [1])


def capsule_specs(name: str, shapes: list[Shape], search_lengths: bool, max_capsules: int = 1):
    """``(geometry fields of link name's LinkSpec, [LinkSpec of its extra capsules])``: the largest of
    :func:`link_capsules` is the link's own capsule; every further one a zero-DOF child of the link,
    in its frame (``offset`` 0, ``attach`` 0), named ``name + EXTRA_CAPSULE + k``.  Only the link's own
    capsule length is searched with ``search_lengths``."""
    caps = link_capsules(shapes, max_capsules)

    def geom(cap, search):
        start, d, length, radius = cap
        return dict(seg_start=tuple(map(float, start)), seg_dir=tuple(map(float, d)), length=float(length),
                    radius=float(radius), length_range=length_range(length, search))

    extras = [LinkSpec(name=f"{name}{EXTRA_CAPSULE}{k}", parent=name, joint="fixed", offset=(0.0, 0.0, 0.0),
                       rest_matrix=np.eye(3), attach=0.0, body=name, **geom(cap, False))
              for k, cap in enumerate(caps[1:], 2)]
    return geom(caps[0], search_lengths), extras


def length_range(length: float, search: bool):
    """The length search range for ``search_lengths``: ``None`` (fixed) or ``+-LENGTH_SEARCH_FRACTION``."""
    if not search or not length > 0:
        return None
    return ((1 - LENGTH_SEARCH_FRACTION) * length, (1 + LENGTH_SEARCH_FRACTION) * length)


# --------------------------------------------------------------------------- URDF


def load_urdf(path, *, search_lengths: bool = False, scale_range=(0.5, 2.0),
              max_capsules: int = MAX_CAPSULES) -> Skeleton:
    """Read a URDF file as a :class:`~jaxpose.skeleton.Skeleton` (see the module docstring).

    Args:
      path: the ``.urdf`` file.
      search_lengths: also search every capsule length within +-30 % (default: fixed).
      scale_range: search range of the global scale.
      max_capsules: capsules per link at most (:func:`link_capsules`); the extra ones are fixed
        child links named ``link#capsule2``, ...; 1: one capsule per link.

    Returns:
      The skeleton; link names are the URDF link names (and those of extra capsules).

    Raises:
      SkeletonError: one message naming the file and the problem.
    """
    path = str(path)
    max_capsules = check_max_capsules(max_capsules, path)
    root = _read_xml(path)
    specs, name = _urdf_specs(root, path, search_lengths, max_capsules)
    return build_skeleton(name, specs, scale_range=scale_range, source=path, require_geometry=False)


def _read_xml(path: str) -> ET.Element:
    if not os.path.exists(path):
        raise SkeletonError(f"{path}: skeleton file not found")
    if os.path.isdir(path):
        raise SkeletonError(f"{path}: is a directory, not a skeleton file")
    try:
        return ET.parse(path).getroot()
    except ET.ParseError as e:
        raise SkeletonError(f"{path}: malformed XML: {e}") from None
    except OSError as e:
        raise SkeletonError(f"{path}: cannot read the file ({e.__class__.__name__}: {e})") from None


def _numbers(text, n, what, default, fail):
    if text is None:
        return np.asarray(default, float)
    try:
        a = np.array([float(x) for x in text.split()], float)
    except ValueError:
        a = None
    if a is None or a.shape != (n,) or not np.all(np.isfinite(a)):
        fail(f"{what} must be {n} number{'s' if n > 1 else ''}, got {text!r}")
    return a


def _origin(elem, what, fail):
    o = elem.find("origin") if elem is not None else None
    if o is None:
        return np.zeros(3), np.eye(3)
    xyz = _numbers(o.get("xyz"), 3, f"{what} <origin xyz>".strip(), (0, 0, 0), fail)
    rpy = _numbers(o.get("rpy"), 3, f"{what} <origin rpy>".strip(), (0, 0, 0), fail)
    return xyz, rpy_matrix(rpy)


MESH_FORMATS = (".obj", ".stl")


def find_mesh_file(filename: str, base: str) -> str | None:
    """The mesh file a URDF ``filename`` names, looked up beside the URDF file in folder
    ``base`` (see the module docstring), or ``None`` when not found or not a readable format."""
    if os.path.splitext(filename)[1].lower() not in MESH_FORMATS:
        return None
    candidates = []
    if filename.startswith("package://"):
        rest = filename[len("package://"):]
        tail = rest.split("/", 1)[1] if "/" in rest else rest
        folder = os.path.abspath(base)
        for _ in range(4):  # the URDF's folder and three above it
            candidates += [os.path.join(folder, rest), os.path.join(folder, tail)]
            folder = os.path.dirname(folder)
    else:
        name = filename[len("file://"):] if filename.startswith("file://") else filename
        candidates.append(name if os.path.isabs(name) else os.path.join(base, name))
    return next((c for c in candidates if os.path.isfile(c)), None)


def read_mesh_vertices(path: str) -> np.ndarray:
    """Vertices ``(n, 3)`` of a Wavefront ``.obj`` or an STL file (binary or ASCII).

    Raises ``ValueError`` for a file that holds no vertex or is malformed.
    """
    try:
        with open(path, "rb") as f:
            raw = f.read(64 << 20)
    except OSError as e:
        raise ValueError(f"cannot read the mesh ({e.strerror or e})") from None
    ext = os.path.splitext(path)[1].lower()
    rows = []
    binary_size = len(raw) >= 84 and len(raw) == 84 + 50 * int.from_bytes(raw[80:84], "little")
    if ext == ".stl" and (binary_size or not raw[:5].lower().startswith(b"solid")):  # ASCII starts with "solid"
        if len(raw) < 84:
            raise ValueError("not an STL file (shorter than its 84-byte header)")
        n = int.from_bytes(raw[80:84], "little")
        if len(raw) < 84 + 50 * n:
            raise ValueError(f"binary STL announces {n} triangles but holds {(len(raw) - 84) // 50}")
        tri = np.frombuffer(raw, np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")]), n, 84)
        v = tri["v"].reshape(-1, 3).astype(float)
    else:
        key = b"v" if ext == ".obj" else b"vertex"
        for line in raw.splitlines():
            parts = line.split()
            if len(parts) >= 4 and parts[0] == key:
                try:
                    rows.append([float(x) for x in parts[1:4]])
                except ValueError:
                    raise ValueError(f"malformed vertex line {line[:60].decode('utf-8', 'replace')!r}") from None
        v = np.asarray(rows, float).reshape(-1, 3)
    if v.shape[0] == 0:
        raise ValueError("the mesh holds no vertex")
    if not np.all(np.isfinite(v)):
        raise ValueError("the mesh has non-finite vertex coordinates")
    v = np.unique(v, axis=0)
    if v.shape[0] > 4096:  # only the convex hull matters for an enclosing capsule
        try:
            from scipy.spatial import ConvexHull

            v = v[ConvexHull(v).vertices]
        except Exception:  # noqa: BLE001 - flat or degenerate mesh: keep every vertex
            pass
    return v


def _urdf_geometry(link, where, fail, base: str = ".") -> list[Shape]:
    elems = link.findall("collision") or link.findall("visual")
    shapes = []
    for k, el in enumerate(elems):
        what = f"{where} <{el.tag}> #{k + 1}"
        geo = el.find("geometry")
        if geo is None or len(geo) == 0:
            fail(f"{what} has no <geometry>")
        g = geo[0]
        pos, R = _origin(el, what, fail)

        def need(key, n=1):
            if g.get(key) is None:
                fail(f"{what} <{g.tag}> needs a {key!r} attribute")
            v = _numbers(g.get(key), n, f"{what} <{g.tag} {key}>", None, fail)
            return float(v[0]) if n == 1 else v

        if g.tag == "sphere":
            shapes.append(sphere_shape(pos, abs(need("radius"))))
        elif g.tag in ("cylinder", "capsule"):
            make = cylinder_shape if g.tag == "cylinder" else capsule_shape
            shapes.append(make(pos, R, abs(need("radius")), 0.5 * abs(need("length"))))
        elif g.tag == "box":
            shapes.append(box_shape(pos, R, 0.5 * need("size", 3)))
        elif g.tag == "mesh":
            s = _numbers(g.get("scale"), 3, f"{what} <mesh scale>", (1, 1, 1), fail)
            mesh = find_mesh_file(g.get("filename") or "", base)
            if mesh is None:
                shapes.append(sphere_shape(pos, DEFAULT_MESH_RADIUS * float(np.max(np.abs(s)))))
            else:
                try:
                    v = read_mesh_vertices(mesh)
                except ValueError as e:
                    fail(f"{what} <mesh filename={g.get('filename')!r}>: {mesh}: {e}")
                shapes.append(points_shape(pos + (v * np.asarray(s, float)) @ np.asarray(R, float).T))
        else:
            fail(f"{what}: unsupported geometry <{g.tag}> (expected box, cylinder, sphere, capsule or mesh)")
    return shapes


def _urdf_specs(root, path, search_lengths, max_capsules=MAX_CAPSULES):
    def fail(msg):
        raise SkeletonError(f"{path}: {msg}")

    if root.tag != "robot":
        fail(f"not a URDF file: the root element is <{root.tag}>, expected <robot>")
    links = {}
    for el in root.findall("link"):
        name = el.get("name")
        if not name:
            fail("every <link> needs a non-empty 'name'")
        if name in links:
            fail(f"duplicate link name {name!r}")
        links[name] = el
    if not links:
        fail("the robot has no links")

    joint_of_child = {}  # child link -> (joint name, spec fields)
    for k, el in enumerate(root.findall("joint")):
        jname = el.get("name") or f"#{k + 1}"
        where = f"joint {jname!r}"
        jfail = lambda msg, where=where: fail(f"{where}: {msg}")  # noqa: E731
        jtype = el.get("type")
        ends = {}
        for tag in ("parent", "child"):
            e = el.find(tag)
            if e is None or not e.get("link"):
                jfail(f"needs a <{tag} link=...> element")
            if e.get("link") not in links:
                jfail(f"refers to a missing {tag} link {e.get('link')!r}")
            ends[tag] = e.get("link")
        if jtype in ("floating", "planar"):
            jfail(f"{jtype} joints are not supported (the root pose is searched anyway; remove the joint "
                  "and let the child link be the root)")
        if jtype not in ("revolute", "continuous", "prismatic", "fixed", "spherical"):
            jfail(f"unknown joint type {jtype!r} (expected revolute, continuous, prismatic, fixed or spherical)")
        child = ends["child"]
        if child in joint_of_child:
            fail(f"closed loop: link {child!r} is the child of both joint {joint_of_child[child][0]!r} "
                 f"and joint {jname!r}")
        if child == ends["parent"]:
            jfail(f"closed loop: link {child!r} is its own parent")
        xyz, R = _origin(el, "", jfail)
        spec = dict(parent=ends["parent"], offset=tuple(xyz), rest_matrix=R, attach=0.0)
        if jtype == "fixed":
            spec["joint"] = "fixed"
        elif jtype == "spherical":
            spec.update(joint="ball", limits=[[-180.0, 180.0]] * 3)
        else:
            axis = _numbers(el.find("axis").get("xyz") if el.find("axis") is not None else None, 3,
                            "<axis xyz>", (1, 0, 0), jfail)
            if not np.linalg.norm(axis) > 0:
                jfail("the joint axis must be a non-zero vector")
            spec.update(joint="slide" if jtype == "prismatic" else "hinge", axis=tuple(axis / np.linalg.norm(axis)))
            if jtype == "continuous":
                spec["limits"] = [[-180.0, 180.0]]
            else:
                lim = el.find("limit")
                if lim is None:
                    jfail(f"a {jtype} joint needs a <limit lower=... upper=...> element")
                lo = _numbers(lim.get("lower"), 1, "<limit lower>", (0.0,), jfail)[0]
                hi = _numbers(lim.get("upper"), 1, "<limit upper>", (0.0,), jfail)[0]
                if lo > hi:
                    jfail(f"inverted limits lower={lo} > upper={hi}")
                # a revolute joint's limits in radians (LinkSpec: degrees); a prismatic joint's in metres
                spec["limits"] = [[lo, hi] if jtype == "prismatic" else [float(np.rad2deg(lo)), float(np.rad2deg(hi))]]
        joint_of_child[child] = (jname, spec)

    roots = [n for n in links if n not in joint_of_child]
    if not roots:
        fail("closed loop: every link is the child of a joint, so there is no root link")
    if len(roots) > 1:
        fail(f"the links do not form one tree: {len(roots)} root links ({', '.join(map(repr, roots[:5]))}"
             f"{', ...' if len(roots) > 5 else ''}); connect them with joints")
    # a cycle not containing the root: walk up from every link
    for name in links:
        seen, n = set(), name
        while n in joint_of_child:
            if n in seen:
                fail(f"closed loop: the joints around link {n!r} form a cycle")
            seen.add(n)
            n = joint_of_child[n][1]["parent"]

    specs, extras = [], []
    for name, el in links.items():
        geom, more = capsule_specs(name, _urdf_geometry(el, f"link {name!r}", fail,
                                                        os.path.dirname(os.path.abspath(path))),
                                   search_lengths, max_capsules)
        if name in joint_of_child:
            specs.append(LinkSpec(name=name, **joint_of_child[name][1], **geom))
        else:
            specs.append(LinkSpec(name=name, parent=None, joint="fixed", attach=0.0, **geom))
        extras += more
    for e in extras:
        if e.name in links:
            fail(f"link {e.parent!r}: the name {e.name!r} of its extra capsule is taken by another link")
    specs += extras
    robot_name = root.get("name") or os.path.splitext(os.path.basename(path))[0]
    return specs, robot_name
