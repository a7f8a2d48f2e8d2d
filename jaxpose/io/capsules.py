"""The capsule approximation of a robot link's geometry (the URDF and MJCF importers share it).

Every geometry becomes a :class:`Shape`: balls whose convex hull encloses it, and the
capsule axes it prefers:

* sphere (:func:`sphere_shape`): a zero-length capsule of the same radius;
* capsule (:func:`capsule_shape`): exact;
* cylinder (:func:`cylinder_shape`): the capsule along its axis with the same radius and
  segment length (it encloses the cylinder; the caps stick out by one radius);
* box (:func:`box_shape`): its eight corners, enclosed normally along its longest side
  with the half-diagonal of the two other sides as radius and the full long side as segment;
* ellipsoid (:func:`ellipsoid_shape`): along its longest axis, the larger other radius;
* point set (:func:`points_shape`, a mesh's vertices): enclosed like the other shapes; a
  link made of meshes only (:data:`MIN_SURFACE_POINTS` vertices or more) gets the capsule
  fitted to those vertices (:func:`surface_capsule`), not the enclosing one, which is much
  fatter than most meshes.

One capsule per link (``max_capsules=1``): :func:`link_capsule`, enclosing all of the link's
shapes.  By default a link gets up to :data:`MAX_CAPSULES` capsules (:func:`link_capsules`):
one per geometry, flat boxes and disks cut into slabs; :func:`capsule_specs` makes the extra
ones fixed child links ``<link>#capsule2``, ... in the link's frame.  A link with no geometry
keeps length 0 and radius 0 and only takes part in the kinematics.  Lengths and radii are
fixed unless ``search_lengths``, which searches the length of every link's own non-zero
capsule within ``+-LENGTH_SEARCH_FRACTION`` (the capsule grows from its start point; child
joints do not move).
"""

from __future__ import annotations

import numpy as np

from ..errors import SkeletonError
from ..geometry import point_segment_distance
from ..skeleton import LinkSpec

LENGTH_SEARCH_FRACTION = 0.3  # search_lengths: lengths vary within +-30 %
# A robot file has its robot's size: the global scale is held at 1 unless searched
# (search_scale), which a folded pose's short spread misleads (docs/robot_files.md#scale).
ROBOT_SCALE_RANGE = (1.0, 1.0)
SEARCHED_SCALE_RANGE = (0.5, 2.0)
_EPS = 1e-12


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
    scores the distance to the capsule's surface from outside and inside alike, so fitted capsules
    place mesh arms far better (see docs/robot_files.md)."""
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
    d = []
    for a, u, length, r in caps:
        a = np.asarray(a, float)
        d.append(np.abs(point_segment_distance(P, a, a + length * np.asarray(u, float), xp=np) - r))
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
