"""The portfolio (``FitConfig.staged_alternatives``): the staged search and the
others, each with its own key and ``staged``, the cheapest answer kept."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from search_cases import PORTFOLIO, skeleton, spider_cloud

from jaxpose.search import Fitter
from jaxpose.search.loop import cheapest, portfolio_keys


def _single(config, staged):
    return dataclasses.replace(config, staged=staged, staged_alternatives=())


@pytest.fixture(scope="module")
def runs():
    """The portfolio through Fitter.run, and its two searches run alone (same programs)."""
    skel, cloud, key = skeleton(), spider_cloud(), jax.random.key(5)
    both = Fitter(skel, PORTFOLIO).run(cloud, key)
    k0, k1 = portfolio_keys(key, 2)
    staged = Fitter(skel, _single(PORTFOLIO, 0.5)).run(cloud, k0)
    flat = Fitter(skel, _single(PORTFOLIO, 0.0)).run(cloud, k1)
    return both, staged, flat


def test_the_portfolio_keeps_the_cheapest_search_and_counts_all(runs):
    both, staged, flat = runs
    assert float(staged.cost) != float(flat.cost)  # two different searches, or the test says nothing
    win = staged if float(staged.cost) <= float(flat.cost) else flat
    np.testing.assert_array_equal(np.asarray(both.genome), np.asarray(win.genome))
    assert float(both.cost) == float(win.cost)
    np.testing.assert_array_equal(np.asarray(both.history), np.asarray(win.history))
    assert int(both.objective_evaluations) == int(staged.objective_evaluations) + int(flat.objective_evaluations)
    assert int(both.gradient_evaluations) == int(staged.gradient_evaluations) + int(flat.gradient_evaluations)


def test_staging_is_traced_and_changes_the_search(runs):
    """A staged and an unstaged search differ only in a traced setting: the same static config."""
    assert _single(PORTFOLIO, 0.5).static() == _single(PORTFOLIO, 0.0).static()
    params = PORTFOLIO.search_params(PORTFOLIO.params())
    assert [float(p.staged) for p in params] == [0.5, 0.0]


def test_cheapest_skips_nan_and_sums_the_counts():
    rows = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *[
        _fake(c, i) for i, c in enumerate([jnp.nan, 0.3, 0.2, 0.25])])
    best = cheapest(rows)
    assert float(best.cost) == pytest.approx(0.2) and float(best.genome[0]) == 2.0
    assert int(best.objective_evaluations) == 10 + 11 + 12 + 13
    assert float(best.distance_evaluations) == pytest.approx(4.0)


def _fake(cost, i):
    from jaxpose.search.state import FitResult

    f = jnp.float32
    return FitResult(None, jnp.full((3,), i, f), None, f(cost), jnp.zeros(2, f), jnp.int32(10 + i), jnp.int32(i),
                     f(1.0), f(0.0))


def test_hypotheses_offer_the_other_searchs_answer_where_it_is_distinct(runs):
    """With hypotheses, the losing search's answer is a candidate: it is among them unless
    every capsule end lies within the hypotheses' min_move of a kept pose (oracle: NumPy)."""
    from jaxpose.objective import cloud_spread
    from jaxpose.search.hypotheses import MIN_MOVE

    _, staged, flat = runs
    lose = flat if float(staged.cost) <= float(flat.cost) else staged
    both = Fitter(skeleton(), PORTFOLIO).run(spider_cloud(), jax.random.key(5), hypotheses=4)
    hyp = both.hypotheses
    assert float(hyp.cost[0]) == float(both.cost) and len(hyp.cost) <= 4
    assert np.all(np.diff(np.asarray(hyp.cost)[1:]) >= 0)  # by cost after the answer
    ends = lambda links: np.concatenate([np.asarray(links.start), np.asarray(links.end)], axis=-2)  # noqa: E731
    move = MIN_MOVE * float(cloud_spread(spider_cloud()))
    far = [np.max(np.linalg.norm(ends(lose.links) - e, axis=-1)) > move for e in ends(hyp.links)]
    present = any(float(c) == float(lose.cost) for c in hyp.cost)
    if all(far) and len(hyp.cost) < 4:
        assert present, "a distinct answer of the other search was left out"
    if present:
        i = [float(c) for c in hyp.cost].index(float(lose.cost))
        np.testing.assert_array_equal(np.asarray(hyp.genome[i]), np.asarray(lose.genome))
