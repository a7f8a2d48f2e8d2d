"""The search as a whole (:mod:`jaxpose.search.loop`): evaluation counts,
determinism, batch == loop (also over traced settings), baselines, bounds.

Expected counts are written from the documented budget
(:func:`search_cases.expected_counts`), not from the code.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from search_cases import (
    ALL,
    CMA,
    GA,
    GA_PLAIN,
    HC,
    IDS,
    ISLANDS,
    N_POINTS,
    expected_counts,
    links_cost,
    run,
    skeleton,
    spider_cloud,
    true_pose,
)

from jaxpose import Cloud, forward_kinematics, genome_layout, rest_pose
from jaxpose.genome import ROOT_ANGLE_LIMITS
from jaxpose.search import Fitter, fit, fit_cloud
from jaxpose.search.coarse import coarse_switch

# --------------------------------------------------------------------------- 5. evaluation counts


@pytest.mark.parametrize("config", ALL, ids=IDS)
def test_exact_evaluation_counts(config):
    res = run(config)
    want_obj, want_grad = expected_counts(config)
    assert int(res.objective_evaluations) == want_obj
    assert int(res.gradient_evaluations) == want_grad
    L = skeleton().num_links
    assert float(res.distance_evaluations) == (want_obj + want_grad) * N_POINTS * L


def test_expected_counts_helper_by_hand():
    # the formula above, spelled out for GA: 4 generations of 16; gradients: 2 memetic epochs *
    # min(20, 16) candidates * 2 steps + the final refinement's min(20, 16) * 3 steps
    assert expected_counts(GA) == (4 * 16, 2 * 16 * 2 + 16 * 3)
    assert expected_counts(GA_PLAIN) == (16 * 4, 0)
    # islands: 4 generations of 8, 2 epochs of 3 candidates * 2 steps, all times 2
    assert expected_counts(ISLANDS) == (4 * 8 * 2, 2 * 3 * 2 * 2)
    # a shorter last epoch is followed by a memetic step too: 5 generations in epochs of 2 -> 3 steps
    assert expected_counts(dataclasses.replace(GA, generations=5))[1] == 3 * 16 * 2 + 16 * 3
    assert expected_counts(HC) == (16 * 4, 1)


# --------------------------------------------------------------------------- 6. determinism


def test_fit_cloud_is_deterministic_and_seeded():
    a, b = run(GA), fit_cloud(spider_cloud(), skeleton(), 0, GA)
    for field in ("genome", "cost", "history", "objective_evaluations", "gradient_evaluations"):
        assert np.array_equal(np.asarray(getattr(a, field)), np.asarray(getattr(b, field))), field
    c = run(GA, seed=1)
    assert not np.array_equal(np.asarray(a.genome), np.asarray(c.genome))


# --------------------------------------------------------------------------- 7. batch == loop


def _batch_vs_loop(config, atol_genome):
    skel = skeleton()
    clouds = [spider_cloud(0), spider_cloud(1)]
    batch = Cloud(jnp.stack([c.points for c in clouds]), jnp.stack([c.weights for c in clouds]))
    keys = jnp.stack([jax.random.key(0), jax.random.key(1)])
    fit_jit = jax.jit(fit, static_argnames="config")
    out = jax.vmap(fit_jit, in_axes=(0, None, 0, None))(batch, skel, keys, config)
    for i in range(2):
        one = run(config, seed=i, cloud_seed=i)  # Fitter: the same steps as fit, compiled by epoch
        assert_same_fit(jax.tree.map(lambda x, i=i: x[i], out), one, atol_genome)
    assert not np.allclose(np.asarray(out.genome[0]), np.asarray(out.genome[1]))


def assert_same_fit(got, want, atol_genome):
    """Two fits' results agree to float32 round-off (their counts exactly)."""
    np.testing.assert_allclose(float(got.cost), float(want.cost), rtol=1e-6)
    np.testing.assert_allclose(np.asarray(got.history), np.asarray(want.history), rtol=1e-6)
    assert int(got.objective_evaluations) == int(want.objective_evaluations)
    assert int(got.gradient_evaluations) == int(want.gradient_evaluations)
    np.testing.assert_allclose(np.asarray(got.genome), np.asarray(want.genome), rtol=0, atol=atol_genome)
    np.testing.assert_allclose(np.asarray(got.links.end), np.asarray(want.links.end), atol=10 * atol_genome)


def test_vmapped_jit_fit_equals_separate_fits():
    _batch_vs_loop(GA_PLAIN, atol_genome=1e-6)


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason=(
    "DEFECT: with gradient refinement on, batch != loop beyond round-off. vmap changes the gradients' "
    "round-off; Adam (eps=1e-8) turns near-zero components (|grad| ~ 2e-8, e.g. leg3_upper.length) into "
    "learning-rate-sized steps, and the memetic step feeds that back into GA selection: genomes differ by "
    "up to 0.02, history and cost by ~1e-4 relative"))
def test_vmapped_jit_fit_equals_separate_fits_with_refinement():
    _batch_vs_loop(GA, atol_genome=1e-4)


# GA_PLAIN with other rates and weights: the same static config, other traced settings
# (no refinement: batch != loop beyond round-off with it, see above)
SWEPT = dataclasses.replace(GA_PLAIN, crossover_rate=0.8, mutation_rate=0.4, branch_mutation_rate=0.1,
                            branch_reset_rate=0.0, objective=dataclasses.replace(
                                GA_PLAIN.objective, sigma_factor=0.35, free_space_weight=2.0, collision_weight=0.3))


def test_fit_vmapped_over_traced_settings_equals_separate_fits():
    """``fit`` vmapped over a batch of :class:`FitParams` (one static config) gives each
    config's own fit, to float32 round-off."""
    configs = [GA_PLAIN, SWEPT]
    assert SWEPT.static() == GA_PLAIN.static()
    params = jax.tree.map(lambda *x: jnp.stack(x), *(c.params() for c in configs))
    cloud, skel, key = spider_cloud(), skeleton(), jax.random.key(0)
    out = jax.jit(jax.vmap(lambda p: fit(cloud, skel, key, GA_PLAIN, p)))(params)
    assert out.genome.shape == (2, genome_layout(skel).size)
    for i, config in enumerate(configs):
        one = run(config)  # a fit of its own (Fitter; SWEPT reuses GA_PLAIN's compiled programs)
        assert_same_fit(jax.tree.map(lambda x, i=i: x[i], out), one, atol_genome=1e-6)
    assert not np.allclose(np.asarray(out.genome[0]), np.asarray(out.genome[1]))


# --------------------------------------------------------------------------- 8. baselines and config errors


@pytest.mark.parametrize("config", [GA_PLAIN, HC, CMA], ids=["ga-plain", "hc", "cma_es"])
def test_baselines_spend_the_ga_search_budget(config):
    res = run(config)
    ga_search = GA.population * GA.generations
    assert (config.population, config.generations) == (GA.population, GA.generations)
    refined = 1 if config.final_refine_steps and config.final_refine_top else 0
    assert int(res.objective_evaluations) == ga_search
    assert int(res.gradient_evaluations) == refined * config.final_refine_steps
    assert res.history.shape == (config.generations,)
    assert np.all(np.diff(np.asarray(res.history)) <= 0)
    assert float(res.cost) <= float(res.history[-1])

# --------------------------------------------------------------------------- 9. bounds


def _rms_spread(points):
    p = np.asarray(points, np.float64)
    return np.sqrt(np.mean(np.sum((p - p.mean(0)) ** 2, -1)))


@pytest.mark.parametrize("config", ALL, ids=IDS)
def test_best_pose_respects_the_search_bounds(config):
    skel, cloud = skeleton(), spider_cloud()
    res = run(config)
    pose = res.pose
    eps = 1e-5
    a, lo, hi = (np.asarray(v) for v in (pose.angles, skel.angle_lo, skel.angle_hi))
    assert np.all(a >= lo - eps) and np.all(a <= hi + eps)
    ln, llo, lhi = (np.asarray(v) for v in (pose.lengths, skel.length_lo, skel.length_hi))
    assert np.all(ln >= llo - eps) and np.all(ln <= lhi + eps)
    s = float(pose.scale)
    assert float(skel.scale_lo) - eps <= s <= float(skel.scale_hi) + eps
    # the scale window: within scale_window of the scale at which the rest model spreads like the cloud
    rest = forward_kinematics(skel, rest_pose(skel))
    t = np.linspace(0, 1, 65)[:, None, None]
    axis_pts = (np.asarray(rest.start)[None] + t * np.asarray(rest.end - rest.start)[None]).reshape(-1, 3)
    s0 = _rms_spread(cloud.points) / _rms_spread(axis_pts)
    w = config.scale_window
    assert s0 / w * 0.9 <= s <= s0 * w * 1.1
    # the root: orientation within its limits, position within the cloud's extent around its centre
    rpy = np.asarray(pose.root_rpy)
    assert np.all(rpy >= ROOT_ANGLE_LIMITS[:, 0] - eps) and np.all(rpy <= ROOT_ANGLE_LIMITS[:, 1] + eps)
    pts = np.asarray(cloud.points, np.float64)
    extent = np.max(np.linalg.norm(pts - pts.mean(0), axis=1))
    assert np.all(np.abs(np.asarray(pose.root_t) - pts.mean(0)) <= extent + 1e-4)
    # what is reported is consistent: links are the pose's, cost is the links' cost
    links = forward_kinematics(skel, pose)
    np.testing.assert_allclose(np.asarray(res.links.start), np.asarray(links.start), atol=1e-5)
    np.testing.assert_allclose(np.asarray(res.links.end), np.asarray(links.end), atol=1e-5)
    np.testing.assert_allclose(float(res.cost), links_cost(cloud, links), rtol=1e-4, atol=1e-6)
    # history: one entry per generation, never worse (within each phase of a coarse-to-fine
    # search: the best cost is on other points after the switch); refinement never makes it worse
    h = np.asarray(res.history)
    switch = coarse_switch(config, N_POINTS) or 0
    assert h.shape == (config.generations,) and np.all(np.diff(h[:switch]) <= 0) and np.all(np.diff(h[switch:]) <= 0)
    assert float(res.cost) <= h[-1]


@pytest.mark.parametrize("config", ALL, ids=IDS)
def test_best_genome_lies_in_the_unit_box(config):
    g = np.asarray(run(config).genome)
    assert g.shape == (genome_layout(skeleton()).size,)
    assert g.min() >= 0.0 and g.max() <= 1.0


# --------------------------------------------------------------------------- 10. accuracy smoke test


def test_ga_beats_the_rest_pose_at_the_cloud_centre():
    skel, cloud = skeleton(), spider_cloud()
    res = run(GA)
    centre = np.asarray(cloud.points).mean(0)
    rest_cost = links_cost(cloud, forward_kinematics(skel, rest_pose(skel, root_t=centre)))
    truth_cost = links_cost(cloud, forward_kinematics(skel, true_pose(skel)))
    assert truth_cost < rest_cost  # the data make sense
    assert float(res.cost) < rest_cost
    assert float(res.wall_time) > 0



def test_hill_climber_never_moves_to_a_worse_point():
    fitter = Fitter(skeleton(), HC)  # the programs run(HC) compiled
    st = fitter.init(spider_cloud(), jax.random.key(0))
    st, _ = fitter.step(st, HC.epoch)
    a = st.algo_state
    np.testing.assert_array_equal(np.asarray(a.mean), np.asarray(a.best_solution))
