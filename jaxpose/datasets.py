"""Synthetic data sets: random natural poses, rendered views with everything known
about them, and the paper's two data sets (pure; no files).  The ray caster,
cameras and sensor model they are made with are :mod:`jaxpose.render`.

Random poses.  :func:`random_pose` draws joint angles around the rest pose within
the limits and rejects poses whose capsules interpenetrate (:func:`self_collisions`).

Views.  :func:`render_view` renders a posed skeleton (world frame) and an optional
scene (a floor, clutter) through the sensor model and keeps the truth: the pose in
the camera and world frames, the capsules, and the fraction of each link that is
seen (:func:`link_visibility`); :func:`render_orbit` places the camera on an orbit
around the subject.

Data sets.  :func:`spider_dataset` (poses x inclinations) and
:func:`humanoid_dataset` (body shapes x poses), a :class:`Sample` per image; each
image is seeded by its place in the set (see ``docs/data.md``).
"""

from __future__ import annotations

import itertools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .camera import KINECT_V1, Intrinsics, project
from .geometry import segment_distance
from .kinematics import forward_kinematics
from .render import (
    Scene, SensorModel, apply_sensor, capsule_scene, empty_scene, floor_scene, merge_scenes, orbit_extrinsics,
    pose_to_camera, random_clutter, render_scene, transform_scene,
)
from .skeleton import Pose, Skeleton


# --------------------------------------------------------------------------- random poses

_fk = jax.jit(forward_kinematics)


def self_collisions(skel: Skeleton, pose: Pose, tolerance: float = 0.8) -> float:
    """Total interpenetration (metres) of capsules that are not parent/child or siblings.

    Two capsules collide when their axes come closer than ``tolerance * (r1 + r2)``.
    """
    links = _fk(skel, pose)
    s, e, r = (np.asarray(a, np.float64) for a in (links.start, links.end, links.radius))
    par = skel.parents
    pairs = [(i, j) for i in range(skel.num_links) for j in range(i + 1, skel.num_links)
             if not (par[j] == i or par[i] == j or par[i] == par[j])]
    if not pairs:
        return 0.0
    i, j = np.array(pairs).T
    gaps = segment_distance(s[i], e[i], s[j], e[j], xp=np) - tolerance * (r[i] + r[j])
    total = 0.0
    for gap in gaps:  # summed in pair order, one pair at a time
        total += max(0.0, -float(gap))
    return total


def random_pose(
    skel: Skeleton,
    rng,
    angle_spread: float = 0.3,
    length_spread: float = 0.0,
    scale: float = 1.0,
    yaw: float | None = None,
    max_tries: int = 30,
) -> Pose:
    """A random natural pose in the skeleton's world frame (root at the origin, upright).

    Joint angles follow a normal distribution around the rest pose (zero clipped
    into the limits) with standard deviation ``angle_spread`` times half the limit
    range, truncated to the limits (resampled, then clipped).  Lengths are uniform
    in ``rest * (1 +- length_spread)`` within the length range.  The root yaw is
    uniform unless given; roll and pitch are 0.  Poses whose capsules interpenetrate
    (:func:`self_collisions`) are rejected; after ``max_tries`` the least colliding
    sample is returned.  ``rng``: a NumPy generator or seed.
    """
    rng = np.random.default_rng(rng)
    lo, hi = np.asarray(skel.angle_lo, np.float64), np.asarray(skel.angle_hi, np.float64)
    rest = np.clip(0.0, lo, hi)
    std = angle_spread * (hi - lo) / 2
    llo, lhi = np.asarray(skel.length_lo, np.float64), np.asarray(skel.length_hi, np.float64)
    lrest = np.asarray(skel.length, np.float64)
    best, best_c = None, np.inf
    for _ in range(max(1, max_tries)):
        q = rest + std * rng.standard_normal(rest.shape)
        for _ in range(5):
            bad = (q < lo) | (q > hi)
            if not bad.any():
                break
            q = np.where(bad, rest + std * rng.standard_normal(rest.shape), q)
        q = np.clip(q, lo, hi)
        lengths = np.clip(lrest * (1 + length_spread * rng.uniform(-1, 1, lrest.shape)), llo, lhi)
        y = rng.uniform(-np.pi, np.pi) if yaw is None else yaw
        pose = Pose(jnp.zeros(3, jnp.float32), jnp.asarray([0.0, 0.0, y], jnp.float32),
                    jnp.asarray(scale, jnp.float32), jnp.asarray(q, jnp.float32), jnp.asarray(lengths, jnp.float32))
        c = self_collisions(skel, pose)
        if c < best_c:
            best, best_c = pose, c
        if c == 0:
            break
    return best


# --------------------------------------------------------------------------- views


class View(NamedTuple):
    """One synthetic depth image and everything known about it (NumPy; camera frame)."""

    depth: np.ndarray  # (H, W) metres after the sensor model (0: no measurement)
    background: np.ndarray | None  # (H, W) the scene without the subject (sensor model applied), or None
    clean: np.ndarray  # (H, W) noise-free depth of subject + scene
    pose: Pose  # the pose in the camera frame
    pose_world: Pose  # the pose in the skeleton's world frame
    start: np.ndarray  # (L, 3) capsule ends in the camera frame
    end: np.ndarray  # (L, 3)
    radius: np.ndarray  # (L,)
    visible: np.ndarray  # (L,) fraction of each link's axis seen unoccluded in the clean image
    T_cam_world: np.ndarray  # (4, 4)
    intrinsics: Intrinsics


def capsule_points(start, end, radius) -> np.ndarray:
    """Corners of the axis-aligned boxes around every capsule: ``(8 L, 3)`` (for framing)."""
    s, e, r = (np.asarray(a, np.float64) for a in (start, end, radius))
    lo = np.minimum(s, e) - r[:, None]
    hi = np.maximum(s, e) + r[:, None]
    corners = [np.where(np.array(m, bool), hi, lo) for m in itertools.product([0, 1], repeat=3)]
    return np.concatenate(corners, 0)


def subject_frame(skel: Skeleton, pose_world: Pose) -> tuple[np.ndarray, float, float]:
    """``(centre, radius, floor_height)`` of a posed skeleton in its world frame."""
    links = _fk(skel, pose_world)
    pts = capsule_points(links.start, links.end, links.radius)
    lo, hi = pts.min(0), pts.max(0)
    centre = (lo + hi) / 2
    return centre, float(np.linalg.norm(hi - lo) / 2), float(lo[2])


def link_visibility(start, end, radius, ids, clean_depth, k: Intrinsics, samples: int = 9,
                    tol: float = 0.01) -> np.ndarray:
    """Fraction of points along each link's axis that project inside the image and are not hidden.

    ``ids`` is the primitive index image of :func:`~jaxpose.render.render_scene` (links first): a
    point is visible when its pixel shows its own link, or anything not in front of it.
    """
    s, e, r = (np.asarray(a, np.float64) for a in (start, end, radius))
    t = np.linspace(0, 1, samples)[None, :, None]
    p = s[:, None] + t * (e - s)[:, None]  # (L, S, 3)
    uv = np.round(project(p, k)).astype(int)
    H, W = clean_depth.shape
    inside = (uv[..., 0] >= 0) & (uv[..., 0] < W) & (uv[..., 1] >= 0) & (uv[..., 1] < H) & (p[..., 2] > 0)
    u = np.clip(uv[..., 0], 0, W - 1)
    v = np.clip(uv[..., 1], 0, H - 1)
    seen = clean_depth[v, u]
    own = ids[v, u] == np.arange(len(s))[:, None]
    ok = inside & (seen > 0) & (own | (seen >= p[..., 2] - r[:, None] - tol))
    return ok.mean(1)


def render_view(
    skel: Skeleton,
    pose_world: Pose,
    T_cam_world,
    k: Intrinsics = KINECT_V1,
    scene: Scene | None = None,
    sensor: SensorModel | None = SensorModel(),
    key: jax.Array | None = None,
    background_frames: int = 8,
) -> View:
    """Render a posed skeleton (world frame) and an optional world-frame ``scene``.

    With a scene the background depth (the scene alone) is returned too, as a
    background model would be captured: the mean of ``background_frames``
    independent draws of the sensor model, valid where any draw measured.
    ``sensor=None`` gives clean images.
    """
    if key is None:
        key = jax.random.PRNGKey(0)
    T = np.asarray(T_cam_world, np.float64)
    pose_cam = pose_to_camera(pose_world, T)
    links = _fk(skel, pose_cam)
    start, end, radius = (np.asarray(a, np.float32) for a in (links.start, links.end, links.radius))
    subject = capsule_scene(start, end, radius)
    bg_scene = transform_scene(scene, T) if scene is not None else None
    full = merge_scenes(subject, bg_scene) if bg_scene is not None else subject
    clean, ids = render_scene(full, k, with_ids=True)
    k_img, k_bg = jax.random.split(key)
    depth = apply_sensor(k_img, clean, sensor) if sensor is not None else clean
    background = None
    if bg_scene is not None:
        bg_clean = render_scene(bg_scene, k)
        if sensor is None:
            background = bg_clean
        else:  # a background model: the mean of several frames, where any frame measured
            frames = np.stack([apply_sensor(kk, bg_clean, sensor) for kk in jax.random.split(k_bg, background_frames)])
            n = (frames > 0).sum(0)
            background = np.where(n > 0, frames.sum(0) / np.maximum(n, 1), 0.0).astype(np.float32)
    vis = link_visibility(start, end, radius, ids, clean, k)
    return View(depth, background, clean, pose_cam, pose_world, start, end, radius, vis, T, k)


def default_distance(radius: float, k: Intrinsics, margin: float = 1.25) -> float:
    """Distance at which a sphere of ``radius`` fills the image's smaller field of view (times ``margin``)."""
    half_fov = min(math.atan2(k.width / 2, k.fx), math.atan2(k.height / 2, k.fy))
    return margin * radius / math.sin(half_fov)


def render_orbit(
    skel: Skeleton,
    pose_world: Pose,
    elevation_deg: float = 20.0,
    azimuth_deg: float = 0.0,
    distance: float | None = None,
    k: Intrinsics = KINECT_V1,
    floor: bool = False,
    clutter: int = 0,
    sensor: SensorModel | None = SensorModel(),
    seed: int = 0,
) -> View:
    """Convenience: camera on an orbit around the subject's centre, optional floor and clutter.

    The floor touches the subject's lowest point; ``distance=None`` frames the subject.
    """
    if distance is None:
        distance = default_distance(subject_frame(skel, pose_world)[1], k)
    return _orbit_view(skel, pose_world, elevation_deg, azimuth_deg, distance, k, floor, clutter, sensor,
                       [seed], [seed, 1])


# --------------------------------------------------------------------------- data sets


class Sample(NamedTuple):
    """One image of a data set: its name, its view and descriptive metadata."""

    name: str
    view: View
    meta: dict


def spider_dataset(
    skel: Skeleton,
    seed: int = 0,
    k: Intrinsics = KINECT_V1,
    num_poses: int = 4,
    inclinations=(0.0, 15.0, 30.0, 45.0, 60.0),
    distance: float = 1.2,
    sensor: SensorModel | None = SensorModel(),
    floor: bool = True,
    clutter: int = 3,
) -> list[Sample]:
    """The paper's spider set: ``num_poses`` poses, each seen from every inclination.

    Poses are :func:`random_pose` draws (seeded by ``seed``); each pose gets its own
    azimuth, so low inclinations show legs hiding legs.  20 images by default.
    """
    out = []
    for p in range(num_poses):
        rng = np.random.default_rng([seed, 0, p])
        pose = random_pose(skel, rng, angle_spread=0.45, length_spread=0.0)
        azimuth = float(rng.uniform(0, 360))
        for j, incl in enumerate(inclinations):
            view = _orbit_view(skel, pose, incl, azimuth, distance, k, floor, clutter, sensor,
                               [seed, 0, p, j], [seed, 0, p])
            out.append(Sample(f"pose{p}_incl{int(round(incl)):02d}", view,
                              dict(pose=p, inclination_deg=float(incl), azimuth_deg=azimuth, distance=distance)))
    return out


def humanoid_dataset(
    skel: Skeleton,
    seed: int = 0,
    k: Intrinsics = KINECT_V1,
    num_subjects: int = 4,
    poses_per_subject: int = 8,
    scales=(0.85, 1.0, 1.1, 0.95),
    distance: float = 2.8,
    elevation_deg: float = 10.0,
    sensor: SensorModel | None = SensorModel(),
    floor: bool = True,
    clutter: int = 3,
) -> list[Sample]:
    """The paper's humanoid set: ``num_subjects`` body shapes x ``poses_per_subject`` natural poses.

    A subject has a global scale (``scales``, cycled) and per-link length factors
    in ``[0.8, 1.2]``, drawn once per orbit of the skeleton's symmetry group so that
    left and right limbs match.  The camera faces the subject from the front half.
    """
    from .metrics import link_orbits

    orbits = link_orbits(skel)
    out = []
    for s in range(num_subjects):
        rng = np.random.default_rng([seed, 1, s])
        factor = np.ones(skel.num_links)
        for orb in orbits:
            factor[list(orb)] = rng.uniform(0.8, 1.2)
        lengths = np.clip(np.asarray(skel.length) * factor, np.asarray(skel.length_lo), np.asarray(skel.length_hi))
        scale = float(scales[s % len(scales)])
        for p in range(poses_per_subject):
            prng = np.random.default_rng([seed, 2, s, p])
            pose = random_pose(skel, prng, angle_spread=0.3, length_spread=0.0, scale=scale, yaw=0.0)
            pose = pose._replace(lengths=jnp.asarray(lengths, jnp.float32))
            azimuth = float(prng.uniform(-60, 60))
            view = _orbit_view(skel, pose, elevation_deg, azimuth, distance, k, floor, clutter, sensor,
                               [seed, 1, s, p], [seed, 1, s])
            out.append(Sample(f"subject{s}_pose{p}", view,
                              dict(subject=s, pose=p, scale=scale, inclination_deg=elevation_deg,
                                   azimuth_deg=azimuth, distance=distance)))
    return out


def _orbit_view(skel, pose, elevation, azimuth, distance, k, floor, clutter, sensor, seed_seq, clutter_seq):
    centre, radius, floor_z = subject_frame(skel, pose)
    T = orbit_extrinsics(centre, elevation, azimuth, distance)
    scene = None
    if floor or clutter:
        scene = empty_scene()
        if floor:
            scene = merge_scenes(scene, floor_scene(floor_z, centre[:2], half_size=max(3.0, 2 * distance)))
        if clutter:
            scene = merge_scenes(scene, random_clutter(np.random.default_rng(clutter_seq), floor_z, centre[:2],
                                                       radius, clutter, azimuth))
    key = jax.random.PRNGKey(int(np.random.default_rng(seed_seq).integers(2**31)))
    return render_view(skel, pose, T, k, scene, sensor, key)
