"""An anytime fit (``Fitter.run(..., time_budget=...)``): it ends after the epoch in which
the budget runs out.  The clock is faked, so nothing here depends on the machine's speed."""

from __future__ import annotations

import dataclasses
import itertools
import types

import numpy as np
import pytest
from search_cases import COARSE, ISLANDS, N_POINTS, OBJ, expected_counts, skeleton, spider_cloud

import jaxpose.search.compiled as compiled
from jaxpose.errors import ConfigError
from jaxpose.search import fit_cloud

# two epochs of two generations, two islands (a config other tests compile too)
LONG = ISLANDS


@pytest.fixture
def slow_clock(monkeypatch):
    """Every reading of the fit's clock is 10 s after the previous one (the fit's clock only)."""
    ticks = itertools.count(0.0, 10.0)
    monkeypatch.setattr(compiled, "time", types.SimpleNamespace(perf_counter=lambda: next(ticks)))


def test_a_budget_ends_the_search_after_the_epoch_it_runs_out_in(slow_clock):
    epochs = []
    res = fit_cloud(spider_cloud(), skeleton(), 0, LONG, progress=lambda g, c, e: epochs.append(g), time_budget=5.0)
    # the clock reads 10 s after the start of the search at the end of the first epoch, past the
    # budget: the search ends there, after 2 of 4 generations
    assert epochs == [2]
    short = dataclasses.replace(LONG, generations=2)
    want_obj, want_grad = expected_counts(short)
    assert int(res.objective_evaluations) == want_obj and int(res.gradient_evaluations) == want_grad
    hist = np.asarray(res.history)
    assert hist.shape == (4,) and np.all(hist[2:] == hist[1])  # the generations not run repeat the last cost
    assert np.isfinite(float(res.cost)) and float(res.cost) <= hist[1]


def test_progress_counts_the_generations_each_search_ran(slow_clock):
    """Two restarts share the budget; each ends after its first epoch: progress and the
    result document count 2 + 2 generations run, not the second search's nominal start."""
    epochs = []
    res = fit_cloud(spider_cloud(), skeleton(), 0, dataclasses.replace(LONG, restarts=2),
                    progress=lambda g, c, e: epochs.append(g), time_budget=5.0)
    assert epochs == [2, 4]
    assert int(res.objective_evaluations) == 2 * expected_counts(dataclasses.replace(LONG, generations=2))[0]


def test_without_a_progress_callback_too(slow_clock):
    res = fit_cloud(spider_cloud(), skeleton(), 0, LONG, time_budget=5.0)
    assert int(res.objective_evaluations) == expected_counts(dataclasses.replace(LONG, generations=2))[0]


def test_an_early_end_before_the_coarse_to_fine_switch_reports_the_cost_on_every_point(slow_clock):
    """Coarse-to-fine scores a few blocks of points until the switch; a fit that ends before
    it must still report (and pick its best by) the cost on every point."""
    from jaxpose import collision_pairs, observe, population_cost

    cloud, skel = spider_cloud(), skeleton()
    res = fit_cloud(cloud, skel, 0, COARSE, time_budget=5.0)
    assert int(res.objective_evaluations) < expected_counts(COARSE)[0]  # it did end early
    pairs = collision_pairs(skel, OBJ.collision_margin)
    lk = res.links
    want = population_cost(observe(cloud, OBJ), lk.start[None], lk.end[None], lk.radius[None], OBJ, None, pairs)[0]
    np.testing.assert_allclose(float(res.cost), float(want), rtol=1e-5)


def test_a_generous_budget_changes_nothing():
    cloud, skel = spider_cloud(), skeleton()
    a = fit_cloud(cloud, skel, 0, LONG)
    b = fit_cloud(cloud, skel, 0, LONG, time_budget=1e6)
    np.testing.assert_array_equal(np.asarray(a.genome), np.asarray(b.genome))
    np.testing.assert_array_equal(np.asarray(a.history), np.asarray(b.history))


@pytest.mark.parametrize("budget", [0.0, -1.0, float("nan"), float("inf")])
def test_a_budget_must_be_a_positive_number(budget):
    with pytest.raises(ConfigError, match="time_budget"):
        fit_cloud(spider_cloud(), skeleton(), 0, LONG, time_budget=budget)


def test_the_result_document_records_the_budget_and_the_generations_run():
    from importlib.resources import files

    from jaxpose import InputOptions, fit_file

    data = files("jaxpose") / "data"
    options = InputOptions(background=str(data / "spider_demo_background.png"), max_points=N_POINTS)
    doc = fit_file(str(data / "spider_demo.png"), "spider", LONG, 0, options, time_budget=1e6).document
    assert doc["time_budget"] == {"seconds": 1e6, "generations_run": LONG.generations}
    assert "time_budget" not in fit_file(str(data / "spider_demo.png"), "spider", LONG, 0, options).document
