"""Synthetic depth images: ray-cast rendering, camera placement and a Kinect-v1-like
sensor model (pure; no files).  The random poses, views with their truth and the
paper's two data sets made with them are :mod:`jaxpose.datasets`.

Rendering.  The camera sits at the origin looking along +z (x right, y down).
Every pixel's ray is intersected analytically with every capsule (a cylinder with
two hemispherical caps; a sphere is a capsule of zero length) and every oriented
box; the nearest hit's z is the pixel's depth, 0 where nothing is hit.

Camera placement.  A skeleton is posed in its own world frame (z up).  A camera
is a 4x4 world->camera matrix ``T_cam_world`` (:func:`look_at`,
:func:`orbit_extrinsics`: elevation above the horizontal, azimuth about world z,
distance to a target).  :func:`pose_to_camera` folds the camera transform into
the root of a :class:`~jaxpose.skeleton.Pose`, so forward kinematics of the
returned pose gives the links directly in the camera frame.

Sensor model (:class:`SensorModel`, each part switchable, driven by one
``jax.random`` key):

1. axial noise, ``sigma(z) = noise_coeff * z**2`` (Khoshelham & Elberink 2012,
   Kinect v1: ``1.425e-3 z^2`` m for a disparity error of 1/2 pixel;
   ``2.85e-3 z^2`` for a full pixel);
2. disparity quantisation: the Kinect v1 measures disparity ``d = f b / z`` in
   1/8 pixel steps (IR focal ``f = 580`` px, baseline ``b = 0.075`` m), so depth
   takes the values ``f b / (n / 8)``; the step grows as ``z^2 / (8 f b)``
   (about 1.1 cm at 2 m);
3. missing pixels along depth discontinuities (silhouette edges): each pixel
   within ``edge_width`` pixels of a jump larger than ``edge_threshold`` is
   dropped with probability ``edge_drop``;
4. random holes: ``num_holes`` discs of random radius dropped anywhere;
5. the working range: depths outside ``[min_range, max_range]`` read 0.

The background image that comes with a scene is a background model: the mean of
several independent sensor draws (see :func:`jaxpose.datasets.render_view`), so
that subtracting it (:func:`~jaxpose.camera.foreground_mask`) leaves little of the scene.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .camera import Intrinsics
from .geometry import matrix_to_rpy, rpy_matrix
from .skeleton import Pose


def pixel_rays(k: Intrinsics) -> jax.Array:
    """Unit ray directions ``(H, W, 3)`` through the pixel centres."""
    v, u = jnp.meshgrid(jnp.arange(k.height, dtype=jnp.float32), jnp.arange(k.width, dtype=jnp.float32), indexing="ij")
    d = jnp.stack([(u - k.cx) / k.fx, (v - k.cy) / k.fy, jnp.ones_like(u)], -1)
    return d / jnp.linalg.norm(d, axis=-1, keepdims=True)


def ray_capsule_distance(rd: jax.Array, pa: jax.Array, pb: jax.Array, r: jax.Array) -> jax.Array:
    """Distance along unit rays ``rd (..., 3)`` from the origin to a capsule (inf: miss)."""
    ro = jnp.zeros(3, rd.dtype)
    ba = pb - pa
    oa = ro - pa
    baba = jnp.dot(ba, ba)
    bard = rd @ ba
    baoa = jnp.dot(ba, oa)
    rdoa = rd @ oa
    oaoa = jnp.dot(oa, oa)
    a = baba - bard * bard
    b = baba * rdoa - baoa * bard
    c = baba * oaoa - baoa * baoa - r * r * baba
    h = b * b - a * c
    safe_a = jnp.where(jnp.abs(a) > 1e-12, a, 1e-12)
    t_body = (-b - jnp.sqrt(jnp.maximum(h, 0.0))) / safe_a
    y = baoa + t_body * bard
    body_hit = (h >= 0) & (jnp.abs(a) > 1e-12) & (y > 0) & (y < baba) & (t_body > 0)

    def sphere(centre):
        oc = ro - centre
        bb = rd @ oc
        cc = jnp.dot(oc, oc) - r * r
        hh = bb * bb - cc
        t = -bb - jnp.sqrt(jnp.maximum(hh, 0.0))
        return jnp.where((hh >= 0) & (t > 0), t, jnp.inf)

    t_caps = jnp.minimum(sphere(pa), sphere(pb))
    return jnp.where(body_hit, t_body, t_caps)


@jax.jit
def _render(rays, start, end, radius):
    def one(carry, cap):
        pa, pb, r = cap
        t = ray_capsule_distance(rays, pa, pb, r)
        t = jnp.where(r > 0, t, jnp.inf)
        return jnp.minimum(carry, t), None

    tmin, _ = jax.lax.scan(one, jnp.full(rays.shape[:-1], jnp.inf, rays.dtype), (start, end, radius))
    z = tmin * rays[..., 2]
    return jnp.where(jnp.isfinite(z), z, 0.0)


def render_capsules(start, end, radius, k: Intrinsics) -> jax.Array:
    """Depth image ``(H, W)`` in metres of capsules given in the camera frame (0: no hit)."""
    return _render(pixel_rays(k), jnp.asarray(start, jnp.float32), jnp.asarray(end, jnp.float32),
                   jnp.asarray(radius, jnp.float32))


# --------------------------------------------------------------------------- scenes


def ray_box_distance(rd: jax.Array, centre: jax.Array, rotation: jax.Array, half: jax.Array) -> jax.Array:
    """Distance along unit rays ``rd (..., 3)`` from the origin to an oriented box (inf: miss).

    The box has centre ``centre (3,)``, axes the columns of ``rotation (3, 3)`` and
    half extents ``half (3,)``.  A camera inside the box sees nothing of it.
    """
    o = rotation.T @ (-centre)  # ray origin in the box frame
    d = rd @ rotation  # ray directions in the box frame
    inv = jnp.where(jnp.abs(d) > 1e-12, 1.0 / jnp.where(jnp.abs(d) > 1e-12, d, 1.0), 1e12)
    t1 = (-half - o) * inv
    t2 = (half - o) * inv
    t_near = jnp.max(jnp.minimum(t1, t2), axis=-1)
    t_far = jnp.min(jnp.maximum(t1, t2), axis=-1)
    hit = (t_near <= t_far) & (t_near > 0)
    return jnp.where(hit, t_near, jnp.inf)


class Scene(NamedTuple):
    """Background geometry (a floor and clutter) as capsules and oriented boxes.

    The frame (world or camera) is the caller's; :func:`transform_scene` moves it.
    Spheres are capsules with ``start == end``.
    """

    cap_start: np.ndarray  # (C, 3)
    cap_end: np.ndarray  # (C, 3)
    cap_radius: np.ndarray  # (C,)
    box_centre: np.ndarray  # (B, 3)
    box_rotation: np.ndarray  # (B, 3, 3) columns: the box axes
    box_half: np.ndarray  # (B, 3) half extents


def empty_scene() -> Scene:
    z3 = np.zeros((0, 3), np.float32)
    return Scene(z3, z3, np.zeros(0, np.float32), z3, np.zeros((0, 3, 3), np.float32), z3)


def merge_scenes(*scenes: Scene) -> Scene:
    return Scene(*(np.concatenate([np.asarray(s[f], np.float32) for s in scenes], 0) for f in range(6)))


def transform_scene(scene: Scene, T: np.ndarray) -> Scene:
    """Apply the rigid 4x4 transform ``T`` to every primitive."""
    T = np.asarray(T, np.float64)
    R, t = T[:3, :3], T[:3, 3]
    f = lambda p: (np.asarray(p, np.float64) @ R.T + t).astype(np.float32)  # noqa: E731
    return Scene(f(scene.cap_start), f(scene.cap_end), np.asarray(scene.cap_radius, np.float32),
                 f(scene.box_centre), (R @ np.asarray(scene.box_rotation, np.float64)).astype(np.float32),
                 np.asarray(scene.box_half, np.float32))


@jax.jit
def _render_scene(rays, cap_start, cap_end, cap_radius, box_centre, box_rotation, box_half):
    C = cap_start.shape[0]

    def closer(carry, t, i):
        tmin, ids = carry
        near = t < tmin
        return jnp.where(near, t, tmin), jnp.where(near, i, ids)

    def cap(carry, c):
        pa, pb, r, i = c
        t = ray_capsule_distance(rays, pa, pb, r)
        return closer(carry, jnp.where(r > 0, t, jnp.inf), i), None

    def box(carry, b):
        c, R, h, i = b
        return closer(carry, ray_box_distance(rays, c, R, h), i), None

    carry = (jnp.full(rays.shape[:-1], jnp.inf, rays.dtype), jnp.full(rays.shape[:-1], -1, jnp.int32))
    if C:
        carry, _ = jax.lax.scan(cap, carry, (cap_start, cap_end, cap_radius, jnp.arange(C, dtype=jnp.int32)))
    if box_centre.shape[0]:
        ids = C + jnp.arange(box_centre.shape[0], dtype=jnp.int32)
        carry, _ = jax.lax.scan(box, carry, (box_centre, box_rotation, box_half, ids))
    tmin, ids = carry
    z = tmin * rays[..., 2]
    hit = jnp.isfinite(z)
    return jnp.where(hit, z, 0.0), jnp.where(hit, ids, -1)


def render_scene(scene: Scene, k: Intrinsics, with_ids: bool = False):
    """Noise-free depth image ``(H, W)`` in metres of a scene given in the camera frame (0: no hit).

    With ``with_ids`` also the index of the primitive seen at every pixel: capsules
    ``0 .. C-1``, then boxes ``C .. C+B-1``; -1 where nothing is hit.
    """
    f = lambda a: jnp.asarray(a, jnp.float32)  # noqa: E731
    z, ids = _render_scene(pixel_rays(k), *(f(a) for a in scene))
    return (np.asarray(z), np.asarray(ids)) if with_ids else np.asarray(z)


def capsule_scene(start, end, radius) -> Scene:
    """A scene made of capsules only (e.g. a posed skeleton's links)."""
    e = empty_scene()
    return e._replace(cap_start=np.asarray(start, np.float32).reshape(-1, 3),
                      cap_end=np.asarray(end, np.float32).reshape(-1, 3),
                      cap_radius=np.asarray(radius, np.float32).reshape(-1))


def floor_scene(height: float, centre=(0.0, 0.0), half_size: float = 3.0, thickness: float = 0.02) -> Scene:
    """A square floor slab (world frame, z up) whose top face lies at ``z = height``."""
    e = empty_scene()
    c = np.array([[centre[0], centre[1], height - thickness / 2]], np.float32)
    return e._replace(box_centre=c, box_rotation=np.eye(3, dtype=np.float32)[None],
                      box_half=np.array([[half_size, half_size, thickness / 2]], np.float32))


def random_clutter(rng, floor_height: float, centre, clear_radius: float, num: int = 3,
                   camera_azimuth_deg: float | None = None, spread: float = 1.2) -> Scene:
    """``num`` random boxes, spheres and upright capsules standing on the floor (world frame).

    They stand between ``clear_radius`` and ``clear_radius + spread`` metres (in
    the floor plane) from ``centre``; with ``camera_azimuth_deg`` only on the side
    away from the camera (behind and beside the subject), so they rarely hide it.
    """
    rng = np.random.default_rng(rng)
    caps, boxes = [], []
    for _ in range(num):
        kind = rng.integers(3)
        size = rng.uniform(0.08, 0.3) * max(clear_radius, 0.3) / 0.6
        if camera_azimuth_deg is None:
            az = rng.uniform(-np.pi, np.pi)
        else:
            az = np.deg2rad(camera_azimuth_deg) + np.pi + rng.uniform(-0.45 * np.pi, 0.45 * np.pi)
        dist = clear_radius + 1.5 * size + rng.uniform(0, spread)
        x, y = centre[0] + dist * np.cos(az), centre[1] + dist * np.sin(az)
        if kind == 0:  # box
            h = np.array([size, size * rng.uniform(0.5, 1.5), size * rng.uniform(0.5, 2.0)])
            yaw = rng.uniform(-np.pi, np.pi)
            R = rpy_matrix(np.array([0.0, 0.0, yaw]))
            boxes.append((np.array([x, y, floor_height + h[2]]), R, h))
        elif kind == 1:  # sphere resting on the floor
            p = np.array([x, y, floor_height + size])
            caps.append((p, p, size))
        else:  # upright capsule (a post)
            r = size * 0.5
            hgt = size * rng.uniform(2.0, 5.0)
            caps.append((np.array([x, y, floor_height + r]), np.array([x, y, floor_height + r + hgt]), r))
    s = empty_scene()
    if caps:
        s = s._replace(cap_start=np.array([c[0] for c in caps], np.float32),
                       cap_end=np.array([c[1] for c in caps], np.float32),
                       cap_radius=np.array([c[2] for c in caps], np.float32))
    if boxes:
        s = s._replace(box_centre=np.array([b[0] for b in boxes], np.float32),
                       box_rotation=np.array([b[1] for b in boxes], np.float32),
                       box_half=np.array([b[2] for b in boxes], np.float32))
    return s


# --------------------------------------------------------------------------- cameras


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """World->camera 4x4 matrix of a camera at ``eye`` looking at ``target``.

    Camera frame: x right, y down, z forward; ``up`` (world) points up in the image.
    """
    eye, target, up = (np.asarray(a, np.float64) for a in (eye, target, up))
    z = target - eye
    n = np.linalg.norm(z)
    if not n > 0:
        raise ValueError("look_at: eye and target coincide")
    z = z / n
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9:  # looking straight along up: pick any right vector
        x = np.cross(z, np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0]))
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])  # rows: camera axes in world coordinates
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = -R @ eye
    return T


def orbit_extrinsics(target, elevation_deg: float, azimuth_deg: float, distance: float) -> np.ndarray:
    """World->camera matrix of a camera ``distance`` metres from ``target``, looking at it.

    ``elevation_deg`` (the inclination) is the angle of the line of sight below the
    horizontal (0: level, 90: straight down); ``azimuth_deg`` is the direction of
    the camera from the target about world z (0: on the +x side, 90: on +y).
    """
    el, az = np.deg2rad(elevation_deg), np.deg2rad(azimuth_deg)
    target = np.asarray(target, np.float64)
    eye = target + distance * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    return look_at(eye, target)


def pose_to_camera(pose: Pose, T_cam_world) -> Pose:
    """The same posed skeleton with its root expressed in the camera frame.

    ``forward_kinematics(skel, pose_to_camera(pose, T))`` equals the world-frame
    links mapped by ``T``.
    """
    T = np.asarray(T_cam_world, np.float64)
    R_cw, t_cw = T[:3, :3], T[:3, 3]
    R = R_cw @ rpy_matrix(np.asarray(pose.root_rpy, np.float64))
    t = R_cw @ np.asarray(pose.root_t, np.float64) + t_cw
    return pose._replace(root_t=jnp.asarray(t, jnp.float32), root_rpy=jnp.asarray(matrix_to_rpy(R), jnp.float32))


# --------------------------------------------------------------------------- sensor model


@dataclass(frozen=True)
class SensorModel:
    """A Kinect-v1-like depth sensor (see the module docstring); every part can be switched off."""

    noise: bool = True
    noise_coeff: float = 1.425e-3  # sigma = noise_coeff * z^2, metres
    quantise: bool = True
    focal_ir: float = 580.0  # IR camera focal length, pixels
    baseline: float = 0.075  # projector-camera baseline, metres
    subpixel: int = 8  # disparity steps per pixel
    edges: bool = True
    edge_threshold: float = 0.04  # metres between neighbouring pixels
    edge_width: int = 1  # pixels either side of a discontinuity
    edge_drop: float = 0.6  # probability that an edge pixel is missing
    holes: bool = True
    num_holes: int = 8
    hole_radius: tuple[float, float] = (1.0, 4.0)  # pixels
    min_range: float = 0.4  # metres; nearer or farther reads 0 (Kinect v1: specified 0.8-4 m)
    max_range: float = 4.0

    @staticmethod
    def off() -> "SensorModel":
        """The ideal sensor: no noise, no quantisation, no missing pixels (the range still applies)."""
        return SensorModel(noise=False, quantise=False, edges=False, holes=False)


def quantise_depth(z: jax.Array, model: SensorModel = SensorModel()) -> jax.Array:
    """Round depth to the nearest depth the disparity quantiser can output (0 stays 0)."""
    fb = model.focal_ir * model.baseline
    d = jnp.where(z > 0, fb / jnp.where(z > 0, z, 1.0), 0.0)
    dq = jnp.round(d * model.subpixel) / model.subpixel
    return jnp.where((z > 0) & (dq > 0), fb / jnp.where(dq > 0, dq, 1.0), 0.0)


def discontinuity_mask(z: jax.Array, threshold: float, width: int = 1) -> jax.Array:
    """Valid pixels within ``width`` pixels of a depth jump > ``threshold`` or of a missing pixel."""
    valid = z > 0
    zp = jnp.pad(z, 1, mode="edge")
    vp = jnp.pad(valid, 1, mode="edge")
    H, W = z.shape
    edge = jnp.zeros_like(valid)
    for dv, du in ((0, 1), (0, -1), (1, 0), (-1, 0)):
        zn = zp[1 + dv: 1 + dv + H, 1 + du: 1 + du + W]
        vn = vp[1 + dv: 1 + dv + H, 1 + du: 1 + du + W]
        edge |= valid & (~vn | (jnp.abs(zn - z) > threshold))
    if width > 1:
        edge = jax.lax.reduce_window(edge.astype(jnp.float32), 0.0, jax.lax.max,
                                     (2 * width - 1, 2 * width - 1), (1, 1), "SAME") > 0
    return edge & valid


def apply_sensor(key: jax.Array, depth, model: SensorModel = SensorModel()) -> np.ndarray:
    """Apply the sensor model to a noise-free depth image (metres, 0: nothing).  Reproducible in ``key``."""
    return np.asarray(_apply_sensor(key, jnp.asarray(depth, jnp.float32), model))


@functools.partial(jax.jit, static_argnames=("model",))
def _apply_sensor(key, z, model: SensorModel):
    k_noise, k_edge, k_centre, k_rad = jax.random.split(key, 4)
    valid = z > 0
    out = z
    if model.edges:
        edge = discontinuity_mask(z, model.edge_threshold, model.edge_width)
        drop = jax.random.uniform(k_edge, z.shape) < model.edge_drop
        valid &= ~(edge & drop)
    if model.noise:
        out = out + model.noise_coeff * out**2 * jax.random.normal(k_noise, z.shape)
    if model.quantise:
        out = quantise_depth(out, model)
    if model.holes and model.num_holes > 0:
        H, W = z.shape
        c = jax.random.uniform(k_centre, (model.num_holes, 2)) * jnp.array([H, W], jnp.float32)
        r = jax.random.uniform(k_rad, (model.num_holes,), minval=model.hole_radius[0], maxval=model.hole_radius[1])
        v, u = jnp.meshgrid(jnp.arange(H, dtype=jnp.float32), jnp.arange(W, dtype=jnp.float32), indexing="ij")
        d2 = (v[None] - c[:, 0, None, None]) ** 2 + (u[None] - c[:, 1, None, None]) ** 2
        valid &= ~jnp.any(d2 <= (r**2)[:, None, None], axis=0)
    valid &= (out >= model.min_range) & (out <= model.max_range)
    return jnp.where(valid, out, 0.0)
