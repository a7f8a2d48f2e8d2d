"""The MuJoCo-rendered tracking experiment's motion (experiments/mujoco_track.py): only the
joints that move move, within their ranges, no faster than two sines allow.  Oracle: the
model's own joint table (MuJoCo) and the sines' largest derivative."""

from __future__ import annotations

import os

import numpy as np
import pytest

pytest.importorskip("mujoco")

import mujoco_track as MT  # noqa: E402

FIXTURES = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "fixtures")


@pytest.mark.parametrize("name, root_joints", [("ant.xml", True), ("quadruped.urdf", False)])
def test_the_motion_moves_the_limbs_within_their_ranges_smoothly(name, root_joints):
    import mujoco

    m = MT.MV.load(os.path.join(FIXTURES, name))[0]
    joints = MT.moving_joints(m, root_joints)
    free = [int(m.jnt_qposadr[j]) for j in range(m.njnt) if m.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE]
    addr = {a for a, _, _ in joints}
    assert joints and not addr & {a + i for a in free for i in range(7)}  # the root's free joint stays
    base = m.qpos0.copy()
    amplitude, frames = 0.2, 45
    q = MT.qpos_motion(m, base, joints, np.random.default_rng(0), frames, amplitude)
    assert q.shape == (frames, m.nq)
    still = [i for i in range(m.nq) if i not in addr]
    np.testing.assert_array_equal(q[:, still], np.repeat(base[None, still], frames, 0))
    for a, lo, hi in joints:
        assert lo <= q[:, a].min() and q[:, a].max() <= hi
        # two sines of amplitude <= amplitude * half range at <= 0.8 Hz: per frame at most their slope
        bound = 2 * amplitude * (hi - lo) / 2 * 2 * np.pi * MT.FREQUENCIES[1] / MT.FPS
        assert np.abs(np.diff(q[:, a])).max() <= bound + 1e-12
    assert np.ptp(q[:, sorted(addr)], axis=0).max() > 0  # and they do move
