"""Rotations and distances between segments, for NumPy and JAX alike.

Every function here is written once over an array namespace ``xp``: ``numpy`` for the
importers, the renderer and the data generator (float64, plain Python control flow
around them), ``jax.numpy`` inside the search and the objective (float32, traced).
``xp=None`` picks ``jax.numpy`` when any argument is a JAX array (a tracer included)
and NumPy otherwise.  The arithmetic is branch-free (``xp.where``), so one
definition serves both and gives NumPy callers the numbers the traced code computes.

Conventions.  ``rpy = (roll, pitch, yaw)`` means ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``
(rotations about the fixed axes x, then y, then z: URDF's ``rpy``).  Quaternions are
``(w, x, y, z)`` (MuJoCo's and ROS's viewpoint order), normalised before use.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

_EPS = 1e-12
# Floor of a squared distance under the square root: keeps the gradient finite where the
# distance is zero without biasing distances (a floor of 1e-12 m^2 made every distance at
# least 1 micrometre, which is not small next to sigma at tiny scales).
TINY_D2 = 1e-30
# |sin(pitch)| above this is gimbal lock: roll and yaw are no longer told apart.
_GIMBAL = 1 - 1e-9


def array_namespace(*arrays):
    """``jax.numpy`` if any of ``arrays`` is a JAX array (or tracer), else ``numpy``."""
    return jnp if any(isinstance(a, jax.Array) for a in arrays) else np


# --------------------------------------------------------------------------- rotations


def rpy_matrix(rpy, xp=None):
    """Rotation matrix ``Rz(yaw) @ Ry(pitch) @ Rx(roll)`` of ``rpy = (roll, pitch, yaw)``.

    Args:
      rpy: angles in radians, shape ``(..., 3)``.
      xp: the array namespace (``None``: that of ``rpy``).

    Returns:
      ``(..., 3, 3)`` rotation matrices.
    """
    xp = xp or array_namespace(rpy)
    r, p, y = rpy[..., 0], rpy[..., 1], rpy[..., 2]
    cr, sr, cp, sp, cy, sy = xp.cos(r), xp.sin(r), xp.cos(p), xp.sin(p), xp.cos(y), xp.sin(y)
    row0 = xp.stack([cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr], -1)
    row1 = xp.stack([sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr], -1)
    row2 = xp.stack([-sp, cp * sr, cp * cr], -1)
    return xp.stack([row0, row1, row2], -2)


def matrix_to_rpy(R, xp=None):
    """Inverse of :func:`rpy_matrix`: ``(roll, pitch, yaw)`` with pitch in ``[-pi/2, pi/2]``.

    At gimbal lock (``|R[2, 0]|`` within 1e-9 of 1) only ``yaw -+ roll`` is defined: roll
    is 0 and yaw takes it all.  NumPy input is computed in float64.

    Args:
      R: rotation matrices ``(..., 3, 3)``.
      xp: the array namespace (``None``: that of ``R``).

    Returns:
      ``(..., 3)`` angles in radians.
    """
    xp = xp or array_namespace(R)
    if xp is np:
        R = np.asarray(R, np.float64)
    sp = xp.clip(-R[..., 2, 0], -1.0, 1.0)
    pitch = xp.arcsin(sp)
    regular = xp.abs(sp) < _GIMBAL
    roll = xp.where(regular, xp.arctan2(R[..., 2, 1], R[..., 2, 2]), 0.0)
    yaw = xp.where(regular, xp.arctan2(R[..., 1, 0], R[..., 0, 0]), xp.arctan2(-R[..., 0, 1], R[..., 1, 1]))
    return xp.stack([roll, pitch, yaw], -1)


def axis_angle_matrix(axis, angle, xp=None):
    """Rodrigues rotation about unit ``axis`` (``(..., 3)``) by ``angle`` (``(...)``, radians).

    ``xp``: the array namespace (``None``: JAX if either argument is a JAX array).
    """
    xp = xp or array_namespace(axis, angle)
    x, y, z = axis[..., 0], axis[..., 1], axis[..., 2]
    c, s = xp.cos(angle), xp.sin(angle)
    C = 1 - c
    row0 = xp.stack([c + x * x * C, x * y * C - z * s, x * z * C + y * s], -1)
    row1 = xp.stack([y * x * C + z * s, c + y * y * C, y * z * C - x * s], -1)
    row2 = xp.stack([z * x * C - y * s, z * y * C + x * s, c + z * z * C], -1)
    return xp.stack([row0, row1, row2], -2)


def quat_to_matrix(q, xp=None):
    """Rotation matrix ``(3, 3)`` of one quaternion ``(w, x, y, z)`` (normalised first).

    NumPy input is computed in float64.  ``xp``: the array namespace (``None``: that of ``q``).
    """
    xp = xp or array_namespace(q)
    q = np.asarray(q, np.float64) if xp is np else q
    w, x, y, z = q / xp.linalg.norm(q)
    return xp.stack([
        xp.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)]),
        xp.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)]),
        xp.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]),
    ])


# --------------------------------------------------------------------------- distances


def point_segment_distance(points, a, b, xp=None):
    """Distances ``(n,)`` of ``points (n, 3)`` to the segment ``a-b`` (``(3,)`` each): the closest
    point by a clamped projection; a segment of length zero is a point.

    ``xp``: the array namespace (``None``: JAX if any argument is a JAX array).
    """
    xp = xp or array_namespace(points, a, b)
    ab = b - a
    t = xp.clip(((points - a) @ ab) / xp.maximum(ab @ ab, _EPS), 0.0, 1.0)
    return xp.linalg.norm(points - (a + t[..., None] * ab), axis=-1)


def segment_distance(p1, q1, p2, q2, axis: int = -1, xp=None):
    """Distance between the segments ``p1-q1`` and ``p2-q2`` (coordinates along ``axis``,
    3 of them; the other axes broadcast).

    The closest points by clamped parameters (Ericson, *Real-Time Collision Detection*,
    5.1.9), written branch-free; a segment of length zero is a point.  Computed on
    separate coordinate arrays (a reduction over a minor axis of 3 is slow on CPU).
    ``xp``: the array namespace (``None``: JAX if any argument is a JAX array).
    """
    xp = xp or array_namespace(p1, q1, p2, q2)
    p1, q1, p2, q2 = xp.broadcast_arrays(*(xp.asarray(v) for v in (p1, q1, p2, q2)))
    if p1.shape[axis] != 3:
        raise ValueError(f"segment_distance: expected 3 coordinates along axis {axis}, got shape {p1.shape}")
    return closest_points(*(xp.moveaxis(v, axis, 0) for v in (p1, q1, p2, q2)), xp=xp)[0]


def _dot3(u, v):
    return u[0] * v[0] + u[1] * v[1] + u[2] * v[2]


def closest_points(p1, q1, p2, q2, xp=None):
    """:func:`segment_distance` on coordinate-first arrays ``(3, ...)``.

    Returns:
      ``(distance, s, t, diff)``: the distance ``(...)``, the closest points' parameters
      ``s`` on ``p1-q1`` and ``t`` on ``p2-q2`` (in ``[0, 1]``), and ``diff (3, ...)``, the
      vector from the closest point on ``p2-q2`` to the one on ``p1-q1``.
    """
    xp = xp or array_namespace(p1, q1, p2, q2)
    d1, d2, r = q1 - p1, q2 - p2, p1 - p2
    a, e, f, c, b = _dot3(d1, d1), _dot3(d2, d2), _dot3(d2, r), _dot3(d1, r), _dot3(d1, d2)
    a_ok, e_ok = a > _EPS, e > _EPS
    a_s, e_s = xp.where(a_ok, a, 1.0), xp.where(e_ok, e, 1.0)
    den = a * e - b * b
    den_ok = den > _EPS * xp.maximum(a * e, _EPS)
    s = xp.where(den_ok, xp.clip((b * f - c * e) / xp.where(den_ok, den, 1.0), 0.0, 1.0), 0.0)
    t = (b * s + f) / e_s
    s = xp.where(t < 0, xp.clip(-c / a_s, 0.0, 1.0), xp.where(t > 1, xp.clip((b - c) / a_s, 0.0, 1.0), s))
    t = xp.clip(t, 0.0, 1.0)
    # degenerate segments: a point against a segment, or two points
    s = xp.where(a_ok, xp.where(e_ok, s, xp.clip(-c / a_s, 0.0, 1.0)), 0.0)
    t = xp.where(e_ok, xp.where(a_ok, t, xp.clip(f / e_s, 0.0, 1.0)), 0.0)
    diff = r + s * d1 - t * d2
    return xp.sqrt(xp.maximum(_dot3(diff, diff), TINY_D2)), s, t, diff
