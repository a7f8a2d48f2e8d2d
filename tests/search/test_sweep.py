"""The limb sweep (jaxpose.search.sweep): its masks, that it finds a limb put wrong
with the rest held, never costs more, and counts its evaluations."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxpose
from jaxpose import ConfigError, FitConfig, forward_kinematics, observe
from jaxpose.genome import decode, encode
from jaxpose.search import init, memetic, sweep
from jaxpose.search.loop import population_cost_fn
from jaxpose.search.state import SearchState

from search_cases import GA, OBJ, descendants, run, skeleton, spider_cloud, true_pose

SWEEP = dataclasses.replace(GA, population=16, limb_sweep=4)


@pytest.mark.parametrize("name", ["humanoid", "spider"])
def test_sweep_masks_are_every_subtrees_joint_angles_in_tree_order(name):
    skel = skeleton(name)
    names = jaxpose.genome_layout(skel).names
    masks = sweep.sweep_masks(skel)
    want = []  # oracle: the parent list and the gene names
    for k in range(skel.num_links):
        links = {skel.link_names[i] for i in descendants(skel, k)}
        row = [n.rsplit(".", 1)[0] in links and ".q" in n for n in names]
        if any(row):
            want.append(row)
    assert masks.tolist() == want
    assert not masks[:, [names.index(n) for n in ("root_roll", "root_pitch", "root_yaw", "scale")]].any()
    np.testing.assert_array_equal(masks, memetic.hop_masks(skel)[:-1][memetic.hop_masks(skel)[:-1].any(1)])


def _setting(skel, cloud, config=SWEEP):
    obs = observe(cloud, OBJ)
    bounds = init.search_bounds(skel, obs, config)
    return obs, bounds


def test_limb_sweep_puts_back_a_limb_put_wrong_and_never_costs_more():
    skel, cloud = skeleton(), spider_cloud()
    obs, bounds = _setting(skel, cloud)
    params = SWEEP.params()
    st = SearchState(None, jax.random.key(0), obs, bounds, params, None, None, None)
    cost = population_cost_fn(skel, SWEEP.static(), st)
    truth = encode(skel, bounds, true_pose(skel))
    leg = sweep.sweep_masks(skel)[0]  # leg0_upper and leg0_lower's joint angles
    wrong = jnp.where(leg, 1.0 - truth, truth)  # that leg mirrored within its ranges
    f_wrong = float(cost(wrong[None])[0])
    assert f_wrong > float(cost(truth[None])[0]) + 1e-3  # the data tells the two apart
    config = dataclasses.replace(SWEEP, population=32, limb_sweep=24)
    g, f = jax.jit(lambda g0, f0: sweep.limb_sweep(skel, config, cost, g0, f0, jax.random.key(1), 0.01))(
        wrong, jnp.float32(f_wrong))
    assert float(f) <= f_wrong
    np.testing.assert_allclose(float(cost(g[None])[0]), float(f), rtol=1e-5)
    placed = forward_kinematics(skel, decode(skel, bounds, g))
    want = forward_kinematics(skel, true_pose(skel))
    legs = [skel.index("leg0_upper"), skel.index("leg0_lower")]
    err = np.linalg.norm(np.asarray(placed.end)[legs] - np.asarray(want.end)[legs], axis=-1)
    assert err.max() < 0.02, err  # back within 2 cm of the truth (the leg is about 0.2 m)


def test_a_fit_with_the_sweep_costs_no_more_and_counts_its_evaluations():
    plain, swept = run(dataclasses.replace(SWEEP, limb_sweep=0)), run(SWEEP)
    assert float(swept.cost) <= float(plain.cost)  # the same search, then the sweep
    skel = skeleton()
    K, P = len(sweep.sweep_masks(skel)), SWEEP.population
    top = min(sweep.SWEEP_REFINE_TOP, P)
    # the documented budget (FitConfig.limb_sweep): every mask's GA generations and Adam steps
    assert int(swept.objective_evaluations - plain.objective_evaluations) == K * P * SWEEP.limb_sweep
    assert int(swept.gradient_evaluations - plain.gradient_evaluations) == K * top * sweep.SWEEP_REFINE_STEPS


@pytest.mark.parametrize("field,value", [("limb_sweep", -1), ("limb_sweep", 2.5), ("limb_sweep", "10")])
def test_bad_sweep_settings_are_named(field, value):
    with pytest.raises(ConfigError, match=field):
        dataclasses.replace(FitConfig(), **{field: value}).validate()
