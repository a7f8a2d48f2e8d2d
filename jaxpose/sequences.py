"""Synthetic motion sequences: a skeleton moving smoothly in front of a fixed
Kinect-like camera, rendered frame after frame with the truth of every frame
(pure; no files).  ``jaxpose render --sequence`` and ``make data`` write them.

Motion.  Every joint value follows ``q0 + sum_k a_k sin(2 pi f_k t + phi_k)``
(two sines per joint, ``f_k`` in ``FREQUENCIES`` Hz, amplitudes a fraction of half
the joint's range), clipped to its limits, around a random natural pose ``q0``
(:func:`~jaxpose.datasets.random_pose`), drawn again while the body would pass
through itself in any frame (:func:`joint_motion`); the root walks along a straight line on
the floor at ``speed`` (in the subject's size per second) and turns about the
vertical at ``turn_rate`` rad/s.  At 30 frames a second a joint moves up to a
few degrees per frame, the root a few centimetres.

Gaps.  With ``gap=(first, length)`` the subject is absent from those frames (the
depth images show the scene alone, as when it walked out of the view) and comes
back elsewhere: moved by ``jump`` times its size across the view and turned by
``GAP_TURN``, on the same motion.

The camera, the floor and the clutter are fixed for a sequence; the sensor noise
is drawn anew for every frame (seeded by the sequence's seed and the frame).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from .camera import KINECT_V1, Intrinsics
from .datasets import View, link_visibility, random_pose, self_collisions, subject_frame, _fk
from .render import (
    SensorModel, apply_sensor, capsule_scene, empty_scene, floor_scene, merge_scenes, orbit_extrinsics,
    pose_to_camera, random_clutter, render_scene, transform_scene,
)
from .skeleton import Pose, Skeleton

FREQUENCIES = (0.25, 0.8)  # Hz: the range of the joints' sines (slow, natural motion)
GAP_TURN = 0.6  # radians the subject has turned when it comes back after a gap
MOTION_TRIES = 30  # draws of the joints' sines before the least colliding is kept


class Sequence(NamedTuple):
    """A rendered motion sequence (NumPy; camera frame)."""

    name: str
    views: list  # per frame a :class:`~jaxpose.datasets.View`, or None when the subject is absent
    depths: list  # per frame the depth image (metres; 0: no measurement)
    background: np.ndarray  # (H, W) the scene without the subject (a background model)
    T_cam_world: np.ndarray
    intrinsics: Intrinsics
    meta: dict


def motion(skel: Skeleton, rng, frames: int, fps: float = 30.0, amplitude: float = 0.25, speed: float = 0.1,
           turn_rate: float = 0.3, scale: float = 1.0, yaw: float = 0.0, angle_spread: float = 0.3,
           gap: tuple[int, int] | None = None, jump: float = 0.6) -> list[Pose]:
    """World-frame poses of a smooth motion (module docstring), one per frame."""
    rng = np.random.default_rng(rng)
    base = random_pose(skel, rng, angle_spread=angle_spread, scale=scale, yaw=yaw)
    qs = joint_motion(skel, base, rng, frames, fps, amplitude)
    size = 2 * subject_frame(skel, base)[1]
    heading = rng.uniform(-np.pi, np.pi)
    direction = np.array([np.cos(heading), np.sin(heading), 0.0])
    v = speed * size * rng.uniform(0.5, 1.0)
    w = turn_rate * rng.uniform(-1.0, 1.0)
    side = np.array([-np.sin(yaw), np.cos(yaw), 0.0])
    poses = []
    for t, q in enumerate(qs):
        s = t / fps
        root_t = v * s * direction
        root_yaw = float(base.root_rpy[2]) + w * s
        if gap is not None and t >= gap[0] + gap[1]:  # back elsewhere
            root_t = root_t + jump * size * side
            root_yaw += GAP_TURN
        poses.append(base._replace(root_t=jnp.asarray(root_t, jnp.float32),
                                   root_rpy=jnp.asarray([0.0, 0.0, root_yaw], jnp.float32),
                                   angles=jnp.asarray(q, jnp.float32)))
    return poses


def joint_motion(skel: Skeleton, base: Pose, rng, frames: int, fps: float, amplitude: float,
                 tries: int = MOTION_TRIES) -> list[np.ndarray]:
    """Every frame's joint values: two sines per joint around ``base``'s, clipped to the limits.
    A draw in which the body passes through itself in any frame
    (:func:`~jaxpose.datasets.self_collisions`) is drawn again, its amplitudes shrunk by a
    third after every ``tries // 3`` failures; after ``tries`` the draw whose worst frame
    collides least is kept."""
    lo, hi = np.asarray(skel.angle_lo, np.float64), np.asarray(skel.angle_hi, np.float64)
    q0 = np.asarray(base.angles, np.float64)
    best, best_c, shrink = None, np.inf, 1.0
    for attempt in range(max(1, tries)):
        amp = shrink * amplitude * (hi - lo) / 2 * rng.uniform(0.3, 1.0, (2,) + q0.shape)
        freq = rng.uniform(*FREQUENCIES, (2,) + q0.shape)
        phase = rng.uniform(0, 2 * np.pi, (2,) + q0.shape)
        qs = [np.clip(q0 + np.sum(amp * np.sin(2 * np.pi * freq * t / fps + phase), 0), lo, hi)
              for t in range(frames)]
        worst = 0.0
        for q in qs:  # the worst frame; stop once it is no better than the best draw
            worst = max(worst, self_collisions(skel, base._replace(angles=jnp.asarray(q, jnp.float32))))
            if worst >= best_c:
                break
        if worst < best_c:
            best, best_c = qs, worst
        if worst == 0:
            break
        if (attempt + 1) % max(1, tries // 3) == 0:
            shrink *= 2 / 3
    return best


def render_sequence(skel: Skeleton, poses: list[Pose], name: str = "sequence", elevation_deg: float = 20.0,
                    azimuth_deg: float = 0.0, distance: float = 2.0, k: Intrinsics = KINECT_V1,
                    floor: bool = True, clutter: int = 3, sensor: SensorModel | None = SensorModel(),
                    seed=0, absent=(), background_frames: int = 8, meta: dict | None = None) -> Sequence:
    """Render ``poses`` (world frame) from a fixed camera aimed at the middle of the path;
    the frames in ``absent`` show the scene without the subject."""
    seed = list(np.atleast_1d(seed))
    absent = set(absent)
    frames_ = [subject_frame(skel, p) for i, p in enumerate(poses) if i not in absent]
    centre = np.mean([f[0] for f in frames_], 0)
    radius = max(f[1] for f in frames_)
    floor_z = min(f[2] for f in frames_)
    T = orbit_extrinsics(centre, elevation_deg, azimuth_deg, distance)
    scene = empty_scene()
    if floor:
        scene = merge_scenes(scene, floor_scene(floor_z, centre[:2], half_size=max(3.0, 2 * distance)))
    if clutter:
        scene = merge_scenes(scene, random_clutter(np.random.default_rng(seed + [1]), floor_z, centre[:2],
                                                   radius, clutter, azimuth_deg))
    bg_scene = transform_scene(scene, T)
    bg_clean = render_scene(bg_scene, k)
    keys = jax.random.split(jax.random.PRNGKey(int(np.random.default_rng(seed).integers(2**31))), len(poses) + 1)
    if sensor is None:
        background = bg_clean
    else:  # a background model: the mean of several frames, where any frame measured
        draws = np.stack([apply_sensor(kk, bg_clean, sensor) for kk in jax.random.split(keys[-1], background_frames)])
        n = (draws > 0).sum(0)
        background = np.where(n > 0, draws.sum(0) / np.maximum(n, 1), 0.0).astype(np.float32)
    views, depths = [], []
    for i, pose in enumerate(poses):
        if i in absent:
            depth = apply_sensor(keys[i], bg_clean, sensor) if sensor is not None else bg_clean
            views.append(None)
            depths.append(depth)
            continue
        pose_cam = pose_to_camera(pose, T)
        links = _fk(skel, pose_cam)
        start, end, rad = (np.asarray(a, np.float32) for a in (links.start, links.end, links.radius))
        clean, ids = render_scene(merge_scenes(capsule_scene(start, end, rad), bg_scene), k, with_ids=True)
        depth = apply_sensor(keys[i], clean, sensor) if sensor is not None else clean
        vis = link_visibility(start, end, rad, ids, clean, k)
        views.append(View(depth, background, clean, pose_cam, pose, start, end, rad, vis, T, k))
        depths.append(depth)
    info = dict(frames=len(poses), elevation_deg=float(elevation_deg), azimuth_deg=float(azimuth_deg),
                distance=float(distance), absent=sorted(absent), **(meta or {}))
    return Sequence(name, views, depths, background, T, k, info)


def spider_sequence(skel: Skeleton, seed: int = 0, frames: int = 90, fps: float = 30.0, gap=None,
                    k: Intrinsics = KINECT_V1, sensor: SensorModel | None = SensorModel(), index: int = 0) -> Sequence:
    """The spider walking and turning on the floor, seen from 1.4 m at 30-50 degrees."""
    rng = np.random.default_rng([seed, 3, 0, index])
    poses = motion(skel, rng, frames, fps, amplitude=0.25, speed=0.15, turn_rate=0.5, angle_spread=0.45,
                   yaw=float(rng.uniform(-np.pi, np.pi)), gap=gap)
    elevation, azimuth = float(rng.uniform(30, 50)), float(rng.uniform(0, 360))
    return _render(skel, poses, "spider", index, gap, seed, elevation, azimuth, 1.4, k, sensor, fps)


def humanoid_sequence(skel: Skeleton, seed: int = 0, frames: int = 90, fps: float = 30.0, gap=None,
                      k: Intrinsics = KINECT_V1, sensor: SensorModel | None = SensorModel(),
                      index: int = 0) -> Sequence:
    """A person moving arms and legs while stepping sideways and turning, seen from the front half at 3.2 m."""
    rng = np.random.default_rng([seed, 3, 1, index])
    scale = float(rng.uniform(0.85, 1.1))
    poses = motion(skel, rng, frames, fps, amplitude=0.2, speed=0.06, turn_rate=0.3, scale=scale, yaw=0.0,
                   gap=gap, jump=0.3)
    azimuth = float(rng.uniform(-45, 45))
    return _render(skel, poses, "humanoid", index, gap, seed, 10.0, azimuth, 3.2, k, sensor, fps, dict(scale=scale))


def robot_sequence(skel: Skeleton, name: str, seed: int = 0, frames: int = 90, fps: float = 30.0, gap=None,
                   k: Intrinsics = KINECT_V1, sensor: SensorModel | None = SensorModel(), index: int = 0,
                   elevation_deg: float = 30.0) -> Sequence:
    """Any skeleton (a robot file's) moving its joints in place and turning slowly, framed by the camera."""
    rng = np.random.default_rng([seed, 3, 2, index])
    poses = motion(skel, rng, frames, fps, amplitude=0.25, speed=0.05, turn_rate=0.3, gap=gap,
                   yaw=float(rng.uniform(-np.pi, np.pi)))
    from .datasets import default_distance

    # framed with room to move, within the sensor's 4 m range
    distance = min(default_distance(subject_frame(skel, poses[0])[1], k, margin=1.3), 3.5)
    return _render(skel, poses, name, index, gap, seed, elevation_deg, float(rng.uniform(0, 360)), distance, k,
                   sensor, fps)


def _render(skel, poses, model, index, gap, seed, elevation, azimuth, distance, k, sensor, fps, meta=None):
    absent = range(gap[0], gap[0] + gap[1]) if gap else ()
    name = f"{model}_{'gap' if gap else 'motion'}{index}"
    return render_sequence(skel, poses, name, elevation, azimuth, distance, k, True, 3, sensor, [seed, 3, index],
                           absent, meta=dict(fps=fps, seed=seed, model=model, gap=list(gap) if gap else None,
                                             **(meta or {})))
