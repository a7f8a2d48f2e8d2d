"""Independent NumPy (float64) oracles for the pure core.

Written from the documented conventions (``jaxpose/skeleton.py`` module docstring,
``jaxpose/io/skeleton_file.py`` schema, ``jaxpose/objective/__init__.py`` equation 1), not
from the JAX code: a recursive forward kinematics over a *description* of the
links (plain dicts in the native-file schema, angles in degrees), and a brute-force
point-to-capsule-surface cost.

Conventions used:

* ``rpy = (roll, pitch, yaw)`` -> ``Rz(yaw) @ Ry(pitch) @ Rx(roll)``; a ball joint's
  three angles ``q`` act like an rpy rotation after the rest rotation.
* hinge: rotation by ``q0`` about the (normalised) ``axis`` of the rest frame,
  computed here as the matrix exponential of the axis' cross-product matrix.
* ``R_i = R_parent @ R_rest_i @ R_joint_i``;
  ``origin_i = origin_parent + R_parent @ (scale * anchor_i)``;
  ``anchor_i = offset_i + attach_i * (parent capsule end in the parent frame)``,
  roots hang from the root frame with ``anchor = offset``.
* capsule: from ``seg_start`` to ``seg_start + length * seg_dir`` in the link frame,
  every length, offset and radius multiplied by the global scale.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg


def rot_x(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]], float)


def rot_y(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]], float)


def rot_z(a):
    c, s = np.cos(a), np.sin(a)
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]], float)


def rpy(roll, pitch, yaw):
    return rot_z(yaw) @ rot_y(pitch) @ rot_x(roll)


def rot_axis(axis, angle):
    """Rotation about ``axis`` by ``angle``: ``expm(angle * [axis]_x)``."""
    k = np.asarray(axis, float)
    k = k / np.linalg.norm(k)
    K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return scipy.linalg.expm(angle * K)


def fk_oracle(links, pose):
    """Recursive forward kinematics of a link description.

    ``links``: list of dicts with keys of the native schema (``name``, ``parent``,
    ``joint``, ``offset``, ``attach``, ``rest`` (degrees), ``axis``, ``length``,
    ``radius``) plus the optional importer keys ``seg_start``, ``seg_dir``, in any
    order.  ``pose``: dict with ``root_t``, ``root_rpy``, ``scale``, ``angles``
    (name -> 3 radians; a slide's first value in metres) and ``lengths`` (name -> metres at scale 1; default: the
    description's ``length``).

    Returns ``{name: dict(R, origin, start, end, radius)}`` in float64.
    """
    by_name = {l["name"]: l for l in links}
    scale = float(pose["scale"])
    R_root = rpy(*np.asarray(pose["root_rpy"], float))
    t_root = np.asarray(pose["root_t"], float)
    out = {}

    def seg(l, length):
        s0 = np.asarray(l.get("seg_start", (0.0, 0.0, 0.0)), float)
        d = np.asarray(l.get("seg_dir", (1.0, 0.0, 0.0)), float)
        d = d / np.linalg.norm(d)
        return s0, s0 + length * d

    def length_of(name):
        return float(pose.get("lengths", {}).get(name, by_name[name].get("length", 0.1)))

    def frame(name):
        if name in out:
            return out[name]
        l = by_name[name]
        parent = l.get("parent")
        offset = np.asarray(l.get("offset", (0.0, 0.0, 0.0)), float)
        if parent is None:
            R_p, t_p = R_root, t_root
            anchor = offset
        else:
            fp = frame(parent)
            R_p, t_p = fp["R"], fp["origin"]
            attach = float(l.get("attach", 1.0))
            _, parent_end = seg(by_name[parent], length_of(parent))
            anchor = offset + attach * parent_end
        R_rest = rpy(*np.deg2rad(np.asarray(l.get("rest", (0.0, 0.0, 0.0)), float)))
        q = np.asarray(pose["angles"].get(name, (0.0, 0.0, 0.0)), float)
        joint = l.get("joint", "ball")
        if joint == "ball":
            R_j = rot_z(q[2]) @ rot_y(q[1]) @ rot_x(q[0])
        elif joint == "hinge":
            R_j = rot_axis(l.get("axis", (0.0, 0.0, 1.0)), q[0])
        elif joint in ("fixed", "slide"):
            R_j = np.eye(3)
        else:
            raise ValueError(joint)
        if joint == "slide":  # the joint frame moves along its axis, given in the rest frame
            axis = np.asarray(l.get("axis", (0.0, 0.0, 1.0)), float)
            anchor = anchor + R_rest @ (q[0] * axis / np.linalg.norm(axis))
        R = R_p @ R_rest @ R_j
        origin = t_p + R_p @ (scale * anchor)
        s0, s1 = seg(l, length_of(name))
        out[name] = dict(
            R=R,
            origin=origin,
            start=origin + R @ (scale * s0),
            end=origin + R @ (scale * s1),
            radius=scale * float(l.get("radius", 0.0)),
        )
        return out[name]

    for l in links:
        frame(l["name"])
    return out


def stack_fk(result, names):
    """``fk_oracle`` output as arrays in the order ``names``: R, origin, start, end, radius."""
    return tuple(np.array([result[n][k] for n in names]) for k in ("R", "origin", "start", "end", "radius"))


def pose_dict(skel, pose):
    """A :class:`jaxpose.skeleton.Pose` (single, unbatched) as the oracle's pose dict."""
    angles = np.asarray(pose.angles, float)
    lengths = np.asarray(pose.lengths, float)
    return dict(
        root_t=np.asarray(pose.root_t, float),
        root_rpy=np.asarray(pose.root_rpy, float),
        scale=float(pose.scale),
        angles={n: angles[i] for i, n in enumerate(skel.link_names)},
        lengths={n: lengths[i] for i, n in enumerate(skel.link_names)},
    )


# --------------------------------------------------------------------------- objective


def spread(points, weights):
    """sigma: sqrt(sum_n w_n |p_n - c|^2 / sum_n w_n), c the weighted centroid."""
    p = np.asarray(points, float)
    w = np.asarray(weights, float)
    keep = w > 0
    p, w = p[keep], w[keep]
    c = (w[:, None] * p).sum(0) / w.sum()
    return float(np.sqrt((w * ((p - c) ** 2).sum(-1)).sum() / w.sum()))


def point_segment_distance(p, a, b):
    """Euclidean distance from point ``p`` to segment ``ab`` (a point when a == b)."""
    p, a, b = (np.asarray(x, float) for x in (p, a, b))
    ab = b - a
    denom = ab @ ab
    if denom == 0.0:
        return float(np.linalg.norm(p - a))
    t = min(1.0, max(0.0, (p - a) @ ab / denom))
    return float(np.linalg.norm(p - (a + t * ab)))


def surface_distances(points, start, end, radius):
    """``d_n = min_l |dist(p_n, segment_l) - r_l|`` by double loop."""
    radius = np.broadcast_to(np.asarray(radius, float), (len(start),))
    out = np.empty(len(points))
    for n, p in enumerate(np.asarray(points, float)):
        out[n] = min(abs(point_segment_distance(p, a, b) - r) for a, b, r in zip(start, end, radius))
    return out


def brute_cost(points, weights, start, end, radius, sigma=None):
    """Equation 1: ``sum_n w_n ln(1 + d_n / sigma) / sum_n w_n`` over the weighted points."""
    w = np.asarray(weights, float)
    keep = w > 0
    pts = np.asarray(points, float)[keep]
    w = w[keep]
    s = spread(pts, w) if sigma is None else float(sigma)
    d = surface_distances(pts, start, end, radius)
    return float((w * np.log1p(d / s)).sum() / w.sum())


def segment_segment_distance(p1, q1, p2, q2, iters: int = 60):
    """Distance between segments ``p1q1`` and ``p2q2`` by ternary search.

    The distance from ``p1 + s (q1 - p1)`` to a segment is convex in ``s``, so its
    minimum over ``s`` in [0, 1] is found by shrinking the bracket (no closed form).
    """
    p1, q1 = np.asarray(p1, float), np.asarray(q1, float)

    def f(s):
        return point_segment_distance(p1 + s * (q1 - p1), p2, q2)

    lo, hi = 0.0, 1.0
    for _ in range(iters):
        m1, m2 = lo + (hi - lo) / 3, hi - (hi - lo) / 3
        if f(m1) <= f(m2):
            hi = m2
        else:
            lo = m1
    return min(f(0.0), f(1.0), f((lo + hi) / 2))


def collision_penalty(start, end, radius, parents, rest_start, rest_end, rest_radius, margin, sigma):
    """The collision term by double loop over link pairs (``jaxpose/objective/__init__.py`` docstring):
    every pair but a link and its parent; the clearance ``rho margin (r_i + r_j)`` with
    ``rho = min(1, d_rest / (margin (R_i + R_j)))`` from the rest pose's distance and
    radii ``R`` (0 for two lines)."""
    total = 0.0
    L = len(start)
    for i in range(L):
        for j in range(i + 1, L):
            if parents[j] == i or parents[i] == j:
                continue
            c_rest = margin * (rest_radius[i] + rest_radius[j])
            if c_rest <= 0:
                continue
            d_rest = segment_segment_distance(rest_start[i], rest_end[i], rest_start[j], rest_end[j])
            rho = min(1.0, d_rest / c_rest)
            d = segment_segment_distance(start[i], end[i], start[j], end[j])
            total += np.log1p(max(0.0, rho * margin * (radius[i] + radius[j]) - d) / sigma)
    return float(total)
