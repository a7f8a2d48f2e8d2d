"""Restarts (``FitConfig.restarts``): the whole fit (portfolio, then turns) run again with
keys of its own, the cheapest answer kept.  Oracle: the fit without restarts, run with
each restart's documented key."""

from __future__ import annotations

import dataclasses

import jax
import numpy as np
import pytest
from search_cases import PORTFOLIO, count_compiles, descendants, skeleton, spider_cloud

from jaxpose.errors import ConfigError
from jaxpose.search import FitConfig, Fitter, fit
from jaxpose.search.loop import RESTART_SALT, cheapest, portfolio_keys, restart_keys

RESTARTS = dataclasses.replace(PORTFOLIO, turns=1, restarts=2)
ONCE = dataclasses.replace(RESTARTS, restarts=1)
SEARCH_PROGRAMS = {f"jit({n})" for n in ("search_init", "search_generations", "search_result", "memetic_apply",
                                         "refine_top")}


@pytest.fixture(scope="module")
def runs():
    """The fit with two restarts (its progress recorded), and the fit without restarts run
    with each restart's key (the same programs)."""
    skel, cloud, key = skeleton(), spider_cloud(), jax.random.key(5)
    seen = []
    both = Fitter(skel, RESTARTS).run(cloud, key, progress=lambda g, c, e: seen.append((g, c, e)))
    with count_compiles() as compiled:  # the restarts' search programs serve the fit without them
        alone = [Fitter(skel, ONCE).run(cloud, k) for k in restart_keys(key, 2)]
    assert not SEARCH_PROGRAMS & set(compiled), compiled  # (small eager ops on new shapes may compile)
    return both, alone, seen


def test_restarts_keep_the_cheapest_fit_and_count_all(runs):
    both, alone, _ = runs
    assert float(alone[0].cost) != float(alone[1].cost)  # two different fits, or the test says nothing
    win = cheapest(alone)
    np.testing.assert_array_equal(np.asarray(both.genome), np.asarray(win.genome))
    assert float(both.cost) == float(win.cost) == min(float(a.cost) for a in alone)
    assert int(both.objective_evaluations) == sum(int(a.objective_evaluations) for a in alone)
    assert int(both.gradient_evaluations) == sum(int(a.gradient_evaluations) for a in alone)


def test_the_first_restart_is_the_fit_without_restarts():
    key = jax.random.key(3)
    keys = restart_keys(key, 3)
    data = lambda k: np.asarray(jax.random.key_data(k))  # noqa: E731
    np.testing.assert_array_equal(data(keys[0]), data(key))
    for r in (1, 2):  # the documented derivation
        np.testing.assert_array_equal(data(keys[r]), data(jax.random.fold_in(key, RESTART_SALT + r)))
    # no restart's searches share a key with another's (the streams are apart)
    every = [tuple(data(k).ravel()) for r in keys for k in portfolio_keys(r, 4)]
    assert len(set(every)) == len(every) == 12


def test_progress_runs_over_every_search_of_every_restart(runs):
    _, _, seen = runs
    cfg = RESTARTS.for_skeleton(skeleton())
    gens = [g for g, _, _ in seen]
    assert gens == sorted(gens) and gens[-1] == cfg.generations * cfg.searches == cfg.generations * 6
    costs = [c for _, c, _ in seen]
    assert all(b <= a for a, b in zip(costs, costs[1:]))  # the best so far, over all searches


@pytest.mark.slow  # two more compilations of the whole traced search (a setting off by default)
def test_the_traced_fit_runs_the_same_restarts():
    """fit (lax.map over the restarts, each a portfolio and a turn) against the traced fit
    without restarts run with each restart's key: the cheaper of the two, to round-off."""
    cloud, skel, key = spider_cloud(), skeleton(), jax.random.key(7)
    run = jax.jit(fit, static_argnames="config")
    both = run(cloud, skel, key, RESTARTS)
    alone = [run(cloud, skel, k, ONCE) for k in restart_keys(key, 2)]
    assert float(alone[0].cost) != float(alone[1].cost)
    assert float(both.cost) == pytest.approx(min(float(a.cost) for a in alone), rel=1e-4)
    assert int(both.objective_evaluations) == sum(int(a.objective_evaluations) for a in alone)


@pytest.mark.parametrize("value", [0, -1, 1.5, True])
def test_impossible_restarts_are_refused(value):
    with pytest.raises(ConfigError, match="restarts"):
        FitConfig(restarts=value).validate()


def test_a_batch_with_restarts_gets_a_program_of_its_own():
    """fit_batch's programs are cached per config: restarts are not in the static config, so
    the cache key must carry them (no compilation here: the programs are built, not run)."""
    from jax.sharding import Mesh

    from jaxpose.parallel import AXIS, _fit_program

    mesh = Mesh(np.array(jax.devices()[:1]), (AXIS,))
    assert RESTARTS.static() == ONCE.static()
    assert _fit_program(RESTARTS, mesh) is not _fit_program(ONCE, mesh)
    assert _fit_program(ONCE, mesh) is _fit_program(dataclasses.replace(ONCE), mesh)


# --------------------------------------------------------------------------- adaptive restarts


def apart_oracle(orbit, a, b) -> float:
    """answers_apart by loops: each link's nearest alike link (same orbit) of the other
    answer by mean end distance, averaged over links, both ways."""
    def one(x, y):
        return np.mean([min((np.linalg.norm(x.start[i] - y.start[j]) + np.linalg.norm(x.end[i] - y.end[j])) / 2
                            for j in range(len(orbit)) if orbit[j] == orbit[i]) for i in range(len(orbit))])
    a, b = (jax.tree_util.tree_map(lambda v: np.asarray(v, np.float64), t) for t in (a, b))
    return (one(a, b) + one(b, a)) / 2


def test_answers_apart_matches_loops_and_a_symmetry_costs_nothing():
    from jaxpose.kinematics import forward_kinematics
    from jaxpose.search.loop import answers_apart
    from search_cases import true_pose

    skel = skeleton()
    a, b = forward_kinematics(skel, true_pose(skel, 0)), forward_kinematics(skel, true_pose(skel, 1))
    assert len(set(skel.orbit)) < skel.num_links  # the spider has alike legs, or the test says less
    got = float(answers_apart(skel, a, b))
    assert got > 0.01 and got == pytest.approx(apart_oracle(skel.orbit, a, b), rel=1e-5)
    assert float(answers_apart(skel, b, a)) == pytest.approx(got, rel=1e-6)
    # two alike legs swapped: the same pose to a user, so no distance
    legs = [i for i, p in enumerate(skel.parents) if p < 0]  # the spider: four legs at its root
    perm = np.arange(skel.num_links)
    for i, j in zip(sorted(descendants(skel, legs[0])), sorted(descendants(skel, legs[1]))):
        perm[i], perm[j] = j, i
    assert skel.orbit[legs[0]] == skel.orbit[legs[1]]
    swapped = jax.tree_util.tree_map(lambda v: v[perm], a)
    assert float(answers_apart(skel, a, swapped)) == 0.0


@pytest.fixture(scope="module")
def round_one():
    """The first restart's answers (run_searches' order) and their disagreement by the oracle,
    as a fraction of the cloud's spread."""
    from jaxpose.objective import cloud_spread
    from jaxpose.search.loop import run_searches

    skel, cloud, key = skeleton(), spider_cloud(), jax.random.key(5)
    fitter = Fitter(skel, ONCE)
    answers = run_searches(skel, fitter.config, fitter.params, key,
                           lambda k, p: fitter._search(cloud, k, p, None, None)[0])
    order = np.argsort([float(r.cost) for r in answers], kind="stable")
    d = apart_oracle(skel.orbit, answers[order[0]].links, answers[order[1]].links)
    return d / float(cloud_spread(cloud))


def test_an_adaptive_restart_runs_only_when_the_first_answers_disagree(runs, round_one):
    """restart_apart just under the first round's disagreement: the second restart runs (the
    fit with two restarts); just over it: it does not (the fit without restarts)."""
    both, alone, _ = runs
    skel, cloud, key = skeleton(), spider_cloud(), jax.random.key(5)
    assert round_one > 0
    for factor, expected in ((0.99, both), (1.01, alone[0])):
        cfg = dataclasses.replace(RESTARTS, restart_apart=round_one * factor)
        got = Fitter(skel, cfg).run(cloud, key)
        np.testing.assert_array_equal(np.asarray(got.genome), np.asarray(expected.genome))
        assert float(got.cost) == float(expected.cost)
        assert int(got.objective_evaluations) == int(expected.objective_evaluations)


@pytest.mark.slow  # two more compilations of the whole traced search (a setting off by default)
def test_the_traced_fit_restarts_adaptively_as_the_fitter(round_one):
    cloud, skel, key = spider_cloud(), skeleton(), jax.random.key(5)
    run = jax.jit(fit, static_argnames="config")
    for factor in (0.99, 1.01):
        cfg = dataclasses.replace(RESTARTS, restart_apart=round_one * factor)
        traced, driven = run(cloud, skel, key, cfg), Fitter(skel, cfg).run(cloud, key)
        assert float(traced.cost) == pytest.approx(float(driven.cost), rel=1e-4)
        assert int(traced.objective_evaluations) == int(driven.objective_evaluations)


@pytest.mark.parametrize("change, match", [({"restart_apart": -0.1}, "restart_apart must be >= 0"),
                                           ({"restart_apart": float("nan")}, "restart_apart"),
                                           ({"restart_apart": 0.2, "staged_alternatives": (), "turns": 0},
                                            "two searches a round")])
def test_impossible_adaptive_restarts_are_refused(change, match):
    with pytest.raises(ConfigError, match=match):
        dataclasses.replace(RESTARTS, **change).validate()
