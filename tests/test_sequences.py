"""Motion sequences (jaxpose.sequences): the joints' motion keeps the body out of itself.
Oracle: ``datasets.self_collisions`` (NumPy capsule distances) on every frame, and the
motion's own formula (two sines per joint, clipped to the limits)."""

from __future__ import annotations

import numpy as np

import jaxpose as jp
from jaxpose import sequences as S
from jaxpose.datasets import random_pose, self_collisions


def _collisions(skel, base, qs):
    return [self_collisions(skel, base._replace(angles=np.asarray(q, np.float32))) for q in qs]


def test_humanoid_motion_never_passes_through_itself():
    # this draw's first sines put an arm through the trunk in 30 of 90 frames (before the redraw existed)
    skel = jp.load_skeleton("humanoid")
    rng = np.random.default_rng([2, 3, 1, 0])  # humanoid_sequence(seed=2, index=0)
    scale = float(rng.uniform(0.85, 1.1))
    poses = S.motion(skel, rng, 90, amplitude=0.2, speed=0.06, turn_rate=0.3, scale=scale, yaw=0.0, jump=0.3)
    assert len(poses) == 90
    assert all(self_collisions(skel, p) == 0.0 for p in poses)


def _draw(skel, base, rng, frames, amplitude):
    lo, hi = np.asarray(skel.angle_lo, np.float64), np.asarray(skel.angle_hi, np.float64)
    q0 = np.asarray(base.angles, np.float64)
    amp = amplitude * (hi - lo) / 2 * rng.uniform(0.3, 1.0, (2,) + q0.shape)
    freq = rng.uniform(*S.FREQUENCIES, (2,) + q0.shape)
    phase = rng.uniform(0, 2 * np.pi, (2,) + q0.shape)
    return [np.clip(q0 + np.sum(amp * np.sin(2 * np.pi * freq * t / 30.0 + phase), 0), lo, hi)
            for t in range(frames)]


def test_joint_motion_is_two_clipped_sines_and_keeps_a_free_first_draw():
    skel = jp.load_skeleton("spider")
    base = random_pose(skel, np.random.default_rng(0), angle_spread=0.45)
    qs = S.joint_motion(skel, base, np.random.default_rng(7), 30, 30.0, 0.25)
    want = _draw(skel, base, np.random.default_rng(7), 30, 0.25)  # the module docstring's formula
    assert max(_collisions(skel, base, want)) == 0.0  # a draw that needs no retry
    np.testing.assert_allclose(np.asarray(qs), np.asarray(want), rtol=0, atol=1e-12)


def test_without_a_free_draw_the_least_colliding_is_kept():
    skel = jp.load_skeleton("humanoid")
    base = random_pose(skel, np.random.default_rng(1))
    # full-range swings collide somewhere in 40 frames; of 3 tries (the amplitude shrunk by a third
    # after each), the draw whose worst frame collides least is kept
    rng = np.random.default_rng(4)
    draws = [_draw(skel, base, rng, 40, 1.0 * (2 / 3) ** k) for k in range(3)]
    worst = [max(_collisions(skel, base, d)) for d in draws]
    assert min(worst) > 0  # none is free, or the test shows nothing
    kept = S.joint_motion(skel, base, np.random.default_rng(4), 40, 30.0, 1.0, tries=3)
    np.testing.assert_allclose(np.asarray(kept), np.asarray(draws[int(np.argmin(worst))]), rtol=0, atol=1e-12)
