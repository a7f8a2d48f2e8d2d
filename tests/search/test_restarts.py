"""Restarts (``FitConfig.restarts``): the whole fit (portfolio, then turns) run again with
keys of its own, the cheapest answer kept.  Oracle: the fit without restarts, run with
each restart's documented key."""

from __future__ import annotations

import dataclasses

import jax
import numpy as np
import pytest
from search_cases import PORTFOLIO, count_compiles, skeleton, spider_cloud

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
