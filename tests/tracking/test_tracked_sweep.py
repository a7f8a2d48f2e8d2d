"""The tracked frames' limb sweep (jaxpose.tracking.local.sweep_limbs): a limb the last
pose has in the wrong place is searched anew in its turn and put back.  Oracles: the
true pose of a synthetic cloud (its capsule ends), and the evaluation count of the
documented budget."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxpose as jp
from jaxpose.search.sweep import sweep_masks
from jaxpose.tracking import TrackConfig
from jaxpose.tracking import local as L
from jaxpose.tracking.local import local_fit
from jaxpose.tracking.step import tracked_counts
from test_tracking import CFG, surface_cloud, true_pose

LEG = ("leg0_upper", "leg0_lower")


@pytest.fixture(scope="module")
def setting():
    skel = jp.load_skeleton("spider")
    truth = true_pose(skel, 0)
    legs = [skel.index(n) for n in LEG]
    q = np.asarray(truth.angles).copy()
    lo, hi = np.asarray(skel.angle_lo), np.asarray(skel.angle_hi)
    q[legs] = np.where(q[legs] >= 0, 0.8 * lo[legs], 0.8 * hi[legs])  # the leg swung to the far side
    wrong = truth._replace(angles=jnp.asarray(q, jnp.float32))
    return skel, truth, wrong, surface_cloud(skel, truth, 0), legs


def _fitter(skel, config, start):
    """One compiled local fit from ``start``; the frame (whose limb is swept) is traced."""
    config = config.for_skeleton(skel)
    run = jax.jit(lambda c, k, t: local_fit(skel, config, c, start, start, k, t))
    return lambda cloud, frame: run(cloud, jax.random.key(0), jnp.int32(frame))


def _leg_error(skel, pose, truth, legs):
    got, want = jp.forward_kinematics(skel, pose), jp.forward_kinematics(skel, truth)
    return float(np.linalg.norm(np.asarray(got.end)[legs] - np.asarray(want.end)[legs], axis=-1).max())


def test_the_limb_in_turn_is_put_back_and_others_are_not_swept(setting):
    skel, truth, wrong, cloud, legs = setting
    assert _leg_error(skel, wrong, truth, legs) > 0.1  # the leg starts well away
    names = np.asarray(jp.genome_layout(skel).names)
    row = 0
    assert {n.split(".")[0] for n in names[sweep_masks(skel)[row]]} == set(LEG)  # row 0: this leg's angles
    config = dataclasses.replace(CFG, population=16, sweep_limbs=1, sweep_generations=8)
    run = _fitter(skel, config, wrong)
    swept = run(cloud, row)  # frame `row` sweeps row `row` (one limb per frame)
    assert _leg_error(skel, swept.pose, truth, legs) < 0.02  # back within 2 cm (the leg is about 0.2 m)
    other = run(cloud, row + 1)  # another limb's turn: this leg stays wrong
    assert _leg_error(skel, other.pose, truth, legs) > 0.05
    off = _fitter(skel, dataclasses.replace(config, sweep_limbs=0), wrong)(cloud, row)
    assert _leg_error(skel, off.pose, truth, legs) > 0.05
    assert float(swept.cost) < float(off.cost)


def test_a_tracked_frame_counts_the_sweep():
    skel = jp.load_skeleton("humanoid")
    c = TrackConfig(population=10, generations=3, refine_top=2, refine_steps=5, sweep_limbs=3, sweep_generations=4,
                    sweep_steps=7)
    assert tracked_counts(skel, c) == (10 * 3 + 3 * 10 * 4, 2 * 5 + 3 * 2 * 7)
    many = dataclasses.replace(c, sweep_limbs=100)  # no more than the skeleton's limbs
    K = len(sweep_masks(skel))
    assert tracked_counts(skel, many) == (10 * 3 + K * 10 * 4, 2 * 5 + K * 2 * 7)
    off = dataclasses.replace(c, sweep_limbs=0)
    assert tracked_counts(skel, off) == (10 * 3, 2 * 5)


def test_a_tracked_frame_runs_the_evaluations_it_counts(setting, monkeypatch):
    # the oracle: every row the objective scores, counted as it runs (the GA, Adam, the sweep, the final score);
    # with the final refinement on, so that the sweep's Adam runs too (off: test_tracking's count)
    skel, truth, wrong, cloud, legs = setting
    rows: list[int] = []
    real = L.local_cost_fn

    def counting(*args, **kwargs):
        cost = real(*args, **kwargs)

        def counted(genomes):
            jax.debug.callback(lambda n: rows.append(int(n)), jnp.int32(genomes.shape[0]))
            return cost(genomes)
        return counted

    monkeypatch.setattr(L, "local_cost_fn", counting)
    fit = dataclasses.replace(CFG.fit, final_refine_steps=5)
    config = dataclasses.replace(CFG, fit=fit, population=6, refine_top=3, refine_steps=4, sweep_limbs=3,
                                 sweep_generations=2, sweep_steps=3)
    jax.block_until_ready(_fitter(skel, config, wrong)(cloud, 5))
    jax.effects_barrier()
    evals, grads = tracked_counts(skel, config.for_skeleton(skel))
    assert sum(rows) == evals + grads + 1  # + the reported cost of the best
    assert grads == 3 * 4 + 3 * 2 * 3  # the local refinement's, then each swept limb's best 2
