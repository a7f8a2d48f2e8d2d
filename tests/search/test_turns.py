"""Turn searches (``FitConfig.turns``): after the portfolio, searches with the root's
orientation held about its answer turned half a turn about each principal axis."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from search_cases import ISLANDS, N_POINTS, PORTFOLIO, capsule_surface_cloud, skeleton, spider_cloud, true_pose

import oracles
from jaxpose import forward_kinematics, observe
from jaxpose.errors import ConfigError
from jaxpose.genome import decode, encode
from jaxpose.geometry import matrix_to_rpy, rpy_matrix
from jaxpose.rest_model import model_samples
from jaxpose.search import FitConfig, Fitter, fit
from jaxpose.search.init import search_bounds, turned_roots
from jaxpose.search.loop import cheapest, portfolio_keys, turn_params

TURNS = dataclasses.replace(PORTFOLIO, turns=2)  # the portfolio's programs serve its turn searches


def _principal_axes_numpy(skel):
    """The rest model's principal axes by NumPy's SVD, major first (an oracle for rest_model)."""
    pts = np.asarray(model_samples(skel), np.float64)
    _, _, vt = np.linalg.svd(pts - pts.mean(0), full_matrices=False)
    return vt.T


@pytest.mark.parametrize("name", ["spider", "humanoid"])
def test_turned_roots_are_half_turns_about_the_principal_axes(name):
    skel = skeleton(name)
    rpy = jnp.asarray([0.4, -0.3, 2.5], jnp.float32)
    R = np.asarray(rpy_matrix(rpy), np.float64)
    got = np.stack([np.asarray(rpy_matrix(r), np.float64) for r in turned_roots(skel, rpy, 3)])
    axes = _principal_axes_numpy(skel)
    # a half turn about unit axis m is 2 m m^T - I (Rodrigues at pi), applied in the model's frame
    want = [R @ (2 * np.outer(m, m) - np.eye(3)) for m in axes.T]
    for g in got:  # each one of the three, each once
        err = [np.abs(g - w).max() for w in want]
        assert min(err) < 1e-4 and sorted(err)[1] > 0.5, err
    spin = 0 if name == "humanoid" else 2  # elongated: about the major axis; flat: about the normal
    np.testing.assert_allclose(got[0], want[spin], atol=1e-4)
    assert turned_roots(skel, rpy, 1).shape == (1, 3)


def test_a_root_window_holds_the_orientation_genes_and_nothing_else():
    skel, cfg = skeleton(), ISLANDS
    obs = observe(spider_cloud(), cfg.objective)
    free = search_bounds(skel, obs, cfg, params=cfg.params())
    assert np.array_equal(np.asarray(free.lo), np.asarray(search_bounds(skel, obs, cfg).lo))
    centre = jnp.asarray([2.8, 1.4, 0.5], jnp.float32)  # pitch 80 degrees: near the roll-pitch-yaw seam
    held = search_bounds(skel, obs, cfg, params=cfg.params().replace(root_rpy=centre, root_window=jnp.float32(0.2)))
    np.testing.assert_allclose(np.asarray(held.lo[3:6]), -0.2, rtol=1e-6)  # a turn relative to the centre
    np.testing.assert_allclose(np.asarray(held.hi[3:6]), 0.2, rtol=1e-6)
    for b, f in ((held.lo, free.lo), (held.hi, free.hi)):
        rest = np.r_[0:3, 6:len(f)]
        assert np.array_equal(np.asarray(b)[rest], np.asarray(f)[rest])
    # every orientation gene value decodes to the centre turned by Rz Ry Rx of the value (NumPy oracle),
    # in the camera's frame: a window as wide about every axis, wherever the centre lies
    C = oracles.rpy(*np.asarray(centre, np.float64))
    rng = np.random.default_rng(0)
    genomes = rng.uniform(0.0, 1.0, (16, len(free.lo))).astype(np.float32)
    genomes[0, 3:6] = 0.5
    for g in genomes:
        pose = decode(skel, held, jnp.asarray(g))
        turn = -0.2 + 0.4 * g[3:6].astype(np.float64)
        np.testing.assert_allclose(np.asarray(rpy_matrix(pose.root_rpy), np.float64), oracles.rpy(*turn) @ C,
                                   atol=2e-6)
        np.testing.assert_allclose(np.asarray(encode(skel, held, pose)), g, atol=2e-5)  # and back
    free_pose = decode(skel, free, jnp.asarray(genomes[1]))  # unheld: the genes are the angles themselves
    np.testing.assert_array_equal(np.asarray(free_pose.root_rpy),
                                  np.asarray(free.lo[3:6] + genomes[1, 3:6] * (free.hi[3:6] - free.lo[3:6])))


def test_a_turn_search_from_a_body_turned_wrong_turns_it_right():
    """The search held about the truth turned back (the first turn of a wrong answer,
    about the spin axis) finds the body's orientation; held about the wrong answer
    itself it cannot, and costs more.  The portfolio's programs, already compiled: a
    turn search compiles nothing.  (About the spider's major axis, upside down, a
    search this small is not reliably dearer: its legs bend back to fit.)"""
    turn = 0
    skel = skeleton()
    truth = true_pose(skel, 3)
    links = forward_kinematics(skel, truth)
    cloud = capsule_surface_cloud(links.start, links.end, links.radius, N_POINTS, 3)
    wrong = turned_roots(skel, truth.root_rpy, 3)[turn]  # the body turned half a turn about one axis
    cfg = TURNS.for_skeleton(skel)
    turned = turn_params(skel, dataclasses.replace(cfg, turns=3), cfg.params(), wrong)[turn]  # about the truth
    fitter = Fitter(skel, cfg)
    held, stuck = (fitter._search(cloud, jax.random.key(0), p, None, None)[0]
                   for p in (turned, turned.replace(root_rpy=wrong)))
    angle = lambda a, b: np.degrees(np.arccos(np.clip((np.trace(np.asarray(rpy_matrix(a)).T  # noqa: E731
                                                                 @ np.asarray(rpy_matrix(b))) - 1) / 2, -1, 1)))
    assert angle(held.pose.root_rpy, truth.root_rpy) < 45 and angle(stuck.pose.root_rpy, truth.root_rpy) > 120
    assert float(held.cost) < float(stuck.cost)


@pytest.fixture(scope="module")
def runs():
    """The fit with turns (every search it ran recorded: key and settings), and the portfolio alone."""
    skel, cloud, key = skeleton(), spider_cloud(), jax.random.key(5)
    fitter, calls = Fitter(skel, TURNS), []
    real = fitter._search

    def spy(cloud, key, params, progress, budget):
        calls.append((np.asarray(jax.random.key_data(key)), params))
        return real(cloud, key, params, progress, budget)

    fitter._search = spy
    return fitter.run(cloud, key), Fitter(skel, dataclasses.replace(TURNS, turns=0)).run(cloud, key), calls


def test_the_fit_runs_each_turn_search_with_its_documented_key_and_window(runs):
    """Oracle: the keys of portfolio_keys after the portfolio's, and turned_roots of the portfolio's answer."""
    _, portfolio, calls = runs
    assert len(calls) == 4
    keys = portfolio_keys(jax.random.key(5), 4)
    for (k, _), want in zip(calls, keys):
        np.testing.assert_array_equal(k, np.asarray(jax.random.key_data(want)))
    centres = np.asarray(turned_roots(skeleton(), portfolio.pose.root_rpy, 2))
    for (_, p), c in zip(calls[2:], centres):
        np.testing.assert_array_equal(np.asarray(p.root_rpy), c.astype(np.float32))
        assert float(p.root_window) == np.float32(TURNS.turn_window) and float(p.staged) == 0.0
    assert all(float(p.root_window) == 0.0 for _, p in calls[:2])  # the portfolio's searches are free


def test_the_turn_searches_start_from_the_portfolios_answer_and_the_cheapest_is_kept(runs):
    """Oracle: the portfolio alone, then each turn search run alone with its documented key and settings."""
    with_turns, portfolio, _ = runs
    skel, cfg = skeleton(), TURNS.for_skeleton(skeleton())
    keys = portfolio_keys(jax.random.key(5), cfg.round_searches)
    alone = [Fitter(skel, cfg)._search(spider_cloud(), k, p, None, None)[0]
             for k, p in zip(keys[2:], turn_params(skel, cfg, cfg.params(), portfolio.pose.root_rpy))]
    for res, c in zip(alone, turned_roots(skel, portfolio.pose.root_rpy, 2)):  # each held in its window
        turn = oracles.rpy(*np.asarray(res.pose.root_rpy, np.float64)) @ oracles.rpy(*np.asarray(c, np.float64)).T
        assert np.all(np.abs(matrix_to_rpy(turn)) <= cfg.turn_window + 1e-4)
    want = cheapest([portfolio] + alone)
    np.testing.assert_array_equal(np.asarray(with_turns.genome), np.asarray(want.genome))
    assert float(with_turns.cost) == float(want.cost) <= float(portfolio.cost)
    assert int(with_turns.objective_evaluations) == 2 * int(portfolio.objective_evaluations)  # 4 searches, not 2


def test_the_traced_fit_runs_the_same_portfolio_and_turns(runs):
    """fit (one traced program: lax.map over the portfolio's searches, then over the turns)
    against the Fitter's programs: equal to round-off."""
    with_turns, _, _ = runs
    traced = jax.jit(fit, static_argnames="config")(spider_cloud(), skeleton(), jax.random.key(5), TURNS)
    assert float(traced.cost) == pytest.approx(float(with_turns.cost), rel=1e-3)
    assert int(traced.objective_evaluations) == int(with_turns.objective_evaluations)


@pytest.mark.parametrize("field,value", [("turns", 4), ("turns", -1), ("turns", 1.5), ("turn_window", 0.0),
                                         ("turn_window", 4.0), ("turn_window", float("nan"))])
def test_impossible_turn_settings_are_refused(field, value):
    with pytest.raises(ConfigError, match=field):
        dataclasses.replace(FitConfig(), **{field: value}).validate()
