"""The limb and pivot sweeps (jaxpose.search.sweep): their masks, that the limb sweep
finds a limb put wrong with the rest held, that a pivot holds its subtree in the world
and puts back a body turned about a limb placed right, that sweeps never cost more,
and count their evaluations."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import tomllib

import jaxpose
from jaxpose import ConfigError, FitConfig, forward_kinematics, observe
from jaxpose.genome import decode, encode
from jaxpose.search import init, memetic, sweep
from jaxpose.search.loop import population_cost_fn
from jaxpose.search.state import SearchState

from oracles import fk_oracle, pose_dict, stack_fk
from search_cases import GA, OBJ, descendants, run, skeleton, spider_cloud, true_pose

SWEEP = dataclasses.replace(GA, population=16, limb_sweep=4)
PIVOT = dataclasses.replace(GA, population=16, pivot_sweep=4)


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


@pytest.mark.parametrize("field,value", [("limb_sweep", -1), ("limb_sweep", 2.5), ("limb_sweep", "10"),
                                         ("pivot_sweep", -2)])
def test_bad_sweep_settings_are_named(field, value):
    with pytest.raises(ConfigError, match=field):
        dataclasses.replace(FitConfig(), **{field: value}).validate()


def test_pivot_links_are_links_with_two_bodies_below_and_joint_angles_elsewhere():
    skel = skeleton("humanoid")
    names = jaxpose.genome_layout(skel).names
    want = [k for k in range(skel.num_links) if len(descendants(skel, k)) >= 2 and any(
        ".q" in n for n in names if n.rsplit(".", 1)[0] not in {skel.link_names[i] for i in descendants(skel, k)})]
    assert sweep.pivot_links(skel).tolist() == want
    assert "l_thigh" in [skel.link_names[k] for k in want] and "l_hand" not in [skel.link_names[k] for k in want]


def _raw_links(name):
    import os
    path = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))), "skeletons",
                        f"{name}.toml")
    with open(path, "rb") as f:
        return tomllib.load(f)["link"]


@pytest.mark.parametrize("link,turned", [("l_thigh", False), ("upper_spine", False), ("r_forearm", False),
                                         ("l_thigh", True), ("r_forearm", True)])
def test_pivot_root_holds_the_pivots_subtree_where_it_was(link, turned):
    """After :func:`pivot_root` the pivot's subtree lies where it lay in the pose it was
    held from, though every other joint angle changed (recursive NumPy FK as the oracle);
    ``turned``: a turn search's genome, whose root angles are a turn relative to a held
    orientation (a window of half a turn, so that the pivot's turn is never clipped)."""
    skel = skeleton("humanoid")
    k = skel.index(link)
    D = jaxpose.genome_layout(skel).size
    b = jaxpose.genome_bounds(skel, jnp.zeros(3), 10.0)
    bounds = jaxpose.genome.Bounds(jnp.asarray(b.lo), jnp.asarray(b.hi))
    if turned:
        bounds = jaxpose.genome.held_bounds(bounds, jnp.asarray([0.3, 1.2, -2.0]), np.pi, jnp.asarray(True))
    rng = np.random.default_rng(3)
    held = jnp.asarray(rng.uniform(0.2, 0.8, D), jnp.float32)
    held_pose = decode(skel, bounds, held)
    want = stack_fk(fk_oracle(_raw_links("humanoid"), pose_dict(skel, held_pose)), skel.link_names)
    others = jnp.asarray(rng.uniform(0.0, 1.0, (5, D)), jnp.float32)
    mask = sweep._pivot_masks(skel)[k]
    pop = jnp.where(mask, others, held[None])
    links = forward_kinematics(skel, held_pose)
    got = sweep.pivot_root(skel, bounds, pop, k, links.R_world_link[k], links.origin[k])
    sub = sorted(descendants(skel, k))
    outside = [i for i in range(skel.num_links) if i not in sub]
    for g in np.asarray(got):
        pose = decode(skel, bounds, jnp.asarray(g))
        R, origin, start, end, _ = stack_fk(fk_oracle(_raw_links("humanoid"), pose_dict(skel, pose)), skel.link_names)
        np.testing.assert_allclose(R[sub], want[0][sub], atol=2e-5)
        np.testing.assert_allclose(np.stack([origin, start, end])[:, sub], np.stack(want[1:4])[:, sub], atol=5e-5)
        moved = np.abs(np.stack([start, end])[:, outside] - np.stack(want[2:4])[:, outside]).max()
        assert moved > 0.05  # the rest of the body did move
    np.testing.assert_array_equal(np.asarray(got)[:, 6:], np.asarray(pop)[:, 6:])  # only the root genes change


def test_pivot_sweep_puts_back_a_body_turned_about_a_limb_placed_right():
    """The spider turned about one leg held where it truly is (that leg's own joint
    drawn anew, the root following): the pivot sweep puts the body back."""
    skel, cloud = skeleton(), spider_cloud()
    config = dataclasses.replace(PIVOT, population=32, pivot_sweep=24)
    obs, bounds = _setting(skel, cloud, config)
    st = SearchState(None, jax.random.key(0), obs, bounds, config.params(), None, None, None)
    cost = population_cost_fn(skel, config.static(), st)
    truth = encode(skel, bounds, true_pose(skel))
    k = skel.index("leg0_upper")
    links = forward_kinematics(skel, decode(skel, bounds, truth))
    own = jnp.asarray(jaxpose.genome_layout(skel).gene_mask([k]))
    wrong = sweep.pivot_root(skel, bounds, jnp.where(own, 1.0 - truth, truth)[None], k, links.R_world_link[k],
                             links.origin[k])[0]
    f_wrong, f_truth = float(cost(wrong[None])[0]), float(cost(truth[None])[0])
    assert f_wrong > f_truth + 0.05  # the body is far off
    g, f = jax.jit(lambda g0, f0: sweep.limb_sweep(skel, config, cost, g0, f0, jax.random.key(1), 0.01, bounds))(
        wrong, jnp.float32(f_wrong))
    np.testing.assert_allclose(float(cost(g[None])[0]), float(f), rtol=1e-5)
    assert float(f) < f_truth + 0.2 * (f_wrong - f_truth)
    placed = np.asarray(forward_kinematics(skel, decode(skel, bounds, g)).end)
    err = np.linalg.norm(placed - np.asarray(links.end), axis=-1)
    assert np.median(err) < 0.03, err  # most of the body back within 3 cm


def test_a_fit_with_the_pivot_sweep_costs_no_more_and_counts_its_evaluations():
    plain, swept = run(dataclasses.replace(PIVOT, pivot_sweep=0)), run(PIVOT)
    assert float(swept.cost) <= float(plain.cost)
    K, P = len(sweep.pivot_links(skeleton())), PIVOT.population
    assert K == 4  # the spider's upper legs
    assert int(swept.objective_evaluations - plain.objective_evaluations) == K * P * PIVOT.pivot_sweep
    assert int(swept.gradient_evaluations - plain.gradient_evaluations) == K * min(2, P) * sweep.SWEEP_REFINE_STEPS
