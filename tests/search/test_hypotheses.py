"""Several answers (``jaxpose.search.hypotheses``): the best distinct poses of a fit."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from search_cases import GA, N_POINTS, count_compiles, skeleton, spider_cloud

from jaxpose import cloud_spread, forward_kinematics
from jaxpose.search import fit_cloud
from jaxpose.search.hypotheses import MIN_MOVE, distinct

# four islands with refinement: candidates from several populations, refined alternatives
HYP = dataclasses.replace(GA, population=8, islands=4, halve_islands_at=())


def _distinct_oracle(ends, costs, k, min_move):
    """The definition, by brute force: walk the rows by cost; keep one that differs from
    every kept row by more than ``min_move`` in its farthest-moved end."""
    kept = []
    for i in sorted(range(len(costs)), key=lambda i: (costs[i], i)):
        if len(kept) == k or not np.isfinite(costs[i]):
            break
        if all(max(np.linalg.norm(ends[i][e] - ends[j][e]) for e in range(ends.shape[1])) > min_move for j in kept):
            kept.append(i)
    return kept


@pytest.mark.parametrize("seed", range(5))
def test_distinct_matches_its_definition(seed):
    rng = np.random.default_rng(seed)
    base = rng.normal(size=(3, 6, 3))
    ends = base[rng.integers(0, 3, 40)] + 0.05 * rng.normal(size=(40, 6, 3))  # clusters of near-copies
    costs = rng.uniform(size=40)
    costs[rng.integers(0, 40, 3)] = np.inf
    for k in (1, 2, 5):
        got = distinct(ends, costs, k, 0.5)
        assert got == _distinct_oracle(ends, costs, k, 0.5)
        assert len(got) <= min(k, 3)  # three clusters: at most three distinct poses


def test_the_first_hypothesis_is_the_answer_and_the_others_are_distinct():
    skel, cloud = skeleton(), spider_cloud()
    res = fit_cloud(cloud, skel, 0, HYP, hypotheses=3)
    plain = fit_cloud(cloud, skel, 0, HYP)
    hyp = res.hypotheses
    assert plain.hypotheses is None
    np.testing.assert_array_equal(np.asarray(hyp.genome[0]), np.asarray(plain.genome))
    assert float(hyp.cost[0]) == float(plain.cost)
    k = hyp.genome.shape[0]
    assert 2 <= k <= 3
    costs = np.asarray(hyp.cost)
    assert np.all(np.isfinite(costs)) and np.all(np.diff(costs[1:]) >= 0)  # the others by cost
    # each hypothesis' links are its own pose's forward kinematics
    for i in range(k):
        pose = type(hyp.pose)(*(np.asarray(x)[i] for x in hyp.pose))
        links = forward_kinematics(skel, pose)
        np.testing.assert_allclose(np.asarray(links.end), np.asarray(hyp.links.end)[i], atol=1e-6)
    ends = np.concatenate([np.asarray(hyp.links.start), np.asarray(hyp.links.end)], axis=1)
    min_move = MIN_MOVE * float(cloud_spread(cloud))
    for i in range(k):
        for j in range(i):
            assert np.max(np.linalg.norm(ends[i] - ends[j], axis=-1)) > min_move


def test_a_second_image_compiles_nothing():
    """The hypotheses' programs have shapes fixed by the config and K, whatever the number of
    distinct poses an image holds."""
    skel, other = skeleton(), spider_cloud(1)
    fit_cloud(spider_cloud(), skel, 0, HYP, hypotheses=3)
    with count_compiles() as names:
        res = fit_cloud(other, skel, 1, HYP, hypotheses=3)
    assert names == [], names
    assert 1 <= res.hypotheses.genome.shape[0] <= 3


def test_hypotheses_must_be_at_least_one():
    with pytest.raises(Exception, match="hypotheses must be >= 1"):
        fit_cloud(spider_cloud(), skeleton(), 0, HYP, hypotheses=0)


def test_the_result_document_records_them(tmp_path):
    """``fit_file(..., hypotheses=K)`` (``jaxpose fit --hypotheses K``) writes each
    hypothesis' cost, links and parameters; the first is the document's own answer."""
    from importlib.resources import files

    from jaxpose import InputOptions, fit_file

    data = files("jaxpose") / "data"
    options = InputOptions(background=str(data / "spider_demo_background.png"), max_points=N_POINTS)
    out = fit_file(str(data / "spider_demo.png"), "spider", HYP, 0, options, hypotheses=2)
    doc = out.document
    hyp = doc["hypotheses"]
    assert 1 <= len(hyp) <= 2 and hyp[0]["cost"] == doc["cost"]
    assert hyp[0]["links"] == doc["links"] and hyp[0]["params"] == doc["params"]
    assert all(set(h) == {"cost", "links", "params"} for h in hyp)
    plain = fit_file(str(data / "spider_demo.png"), "spider", HYP, 0, options).document
    assert "hypotheses" not in plain and plain["cost"] == doc["cost"]
