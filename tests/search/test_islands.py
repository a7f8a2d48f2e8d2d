"""Islands and successive halving (:mod:`jaxpose.search.islands`)."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from search_cases import GA_PLAIN, skeleton, spider_cloud

from jaxpose.search import FitConfig, Fitter
from jaxpose.genome import genome_layout
from jaxpose.search.islands import halve_islands, halving_generations, halving_order, niche_leaders

HALVING = dataclasses.replace(GA_PLAIN, population=8, islands=4, epoch=2, halve_islands_at=(0.5,))


def test_halving_generations_round_to_epoch_ends_and_skip_the_end():
    cfg = FitConfig(generations=300, epoch=25, islands=32)
    assert halving_generations(cfg) == (100, 150, 200, 250)
    assert halving_generations(dataclasses.replace(cfg, halve_islands_at=(0.99, 0.01))) == (25,)
    assert halving_generations(dataclasses.replace(cfg, islands=1)) == ()
    assert halving_generations(HALVING) == (2,)


def test_halving_copies_the_better_half_of_the_islands_and_keeps_their_keys():
    """Two generations, then the next epoch starts with a halving: the worse two of
    four islands (by best cost) take the evolutionary state of the better two, one
    each; keys and evaluation counts stay per island."""
    skel, cloud = skeleton(), spider_cloud()
    plain = dataclasses.replace(HALVING, halve_islands_at=())
    fitter, plain_fitter = Fitter(skel, HALVING), Fitter(skel, plain)
    st = fitter.init(cloud, jax.random.key(3))
    st, _ = fitter.step(st, 2)  # generation 0 -> 2: no halving yet
    st_plain = plain_fitter.init(cloud, jax.random.key(3))
    st_plain, _ = plain_fitter.step(st_plain, 2)
    np.testing.assert_array_equal(np.asarray(st.algo_state.population), np.asarray(st_plain.algo_state.population))
    halved = halve_islands(skel, HALVING.static(), st)
    kept = halve_islands(skel, plain.static(), st)
    np.testing.assert_array_equal(np.asarray(kept.algo_state.population), np.asarray(st.algo_state.population))
    best = np.asarray(st.algo_state.best_fitness)
    better = set(np.argsort(best)[:2].tolist())
    pop, new_pop = np.asarray(st.algo_state.population), np.asarray(halved.algo_state.population)
    sources = []
    for i in range(4):
        match = [j for j in range(4) if np.array_equal(new_pop[i], pop[j])]
        assert match and set(match) <= better
        sources.append(match[0])
        if i in better:
            assert sources[-1] == i
        assert float(halved.algo_state.best_fitness[i]) == float(best[sources[-1]])
    assert sorted(sources) == sorted(list(better) * 2)
    np.testing.assert_array_equal(jax.random.key_data(halved.key), jax.random.key_data(st.key))
    np.testing.assert_array_equal(np.asarray(halved.objective_evaluations), np.asarray(st.objective_evaluations))
    # the compiled epoch halves at its start when the generation count says so
    st2, _ = fitter.step(st, 2)
    ref, _ = plain_fitter.step(halved, 2)
    np.testing.assert_array_equal(np.asarray(st2.algo_state.population), np.asarray(ref.algo_state.population))


def _rot(rpy):
    r, p, y = rpy
    Rx = np.array([[1, 0, 0], [0, np.cos(r), -np.sin(r)], [0, np.sin(r), np.cos(r)]])
    Ry = np.array([[np.cos(p), 0, np.sin(p)], [0, 1, 0], [-np.sin(p), 0, np.cos(p)]])
    Rz = np.array([[np.cos(y), -np.sin(y), 0], [np.sin(y), np.cos(y), 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def test_niche_leaders_match_a_brute_force_oracle():
    """An island leads unless a better one (ties: the lower index) is turned less than
    the angle away; the angle from the axis-angle of the relative rotation."""
    rng = np.random.default_rng(0)
    rpy = rng.uniform(-1, 1, (16, 3)) * np.array([np.pi, np.pi / 2, np.pi])
    rpy[5], rpy[9] = rpy[2] + 0.05, rpy[2] - 0.3  # near copies of island 2
    cost = rng.permutation(16).astype(np.float64)
    cost[7] = cost[3]  # a tie
    cost[11] = np.nan  # never better than anyone
    for deg in (20.0, 45.0, 120.0):
        got = np.asarray(niche_leaders(jnp.asarray(rpy, jnp.float32), jnp.asarray(cost, jnp.float32), deg))
        c = np.where(np.isnan(cost), np.inf, cost)
        want = []
        for i in range(16):
            lead = True
            for j in range(16):
                better = c[j] < c[i] or (c[j] == c[i] and j < i)
                rel = _rot(rpy[i]).T @ _rot(rpy[j])
                angle = np.degrees(np.arccos(np.clip((np.trace(rel) - 1) / 2, -1, 1)))
                if better and angle < deg:
                    lead = False
            want.append(lead)
        np.testing.assert_array_equal(got, want)
        assert got[np.argmin(c)]


@pytest.mark.slow  # niches are off by default (measured without gain): out of the suite's time
def test_niche_halving_keeps_the_best_island_of_each_orientation():
    """Islands 0 and 1 face one way, 2 and 3 the opposite way (costs 1 < 2 < 3 < 4):
    plain halving keeps 0 and 1, niche halving keeps 0 and 2 and copies them into 1 and 3."""
    skel, cloud = skeleton(), spider_cloud()
    niche = dataclasses.replace(HALVING, halve_niche_deg=45.0)
    fitter = Fitter(skel, niche)
    st = fitter.init(cloud, jax.random.key(3))
    st, _ = fitter.step(st, 2)
    i = genome_layout(skel).names.index("root_yaw")
    best = np.array(st.algo_state.best_solution)
    best[:, i - 2 : i + 1] = 0.5  # roll, pitch, yaw all 0
    best[2:, i] = 1.0  # yaw pi: turned half round
    state = st.algo_state.replace(best_solution=jnp.asarray(best),
                                  best_fitness=jnp.asarray([1.0, 2.0, 3.0, 4.0], jnp.float32))
    st = st._replace(algo_state=state)
    assert np.asarray(halving_order(skel, HALVING.static(), st)).tolist() == [0, 1, 2, 3]
    assert np.asarray(halving_order(skel, niche.static(), st)).tolist() == [0, 2, 1, 3]
    halved = halve_islands(skel, niche.static(), st)
    np.testing.assert_array_equal(np.asarray(halved.algo_state.best_fitness), [1.0, 1.0, 3.0, 3.0])
    pop, new_pop = np.asarray(st.algo_state.population), np.asarray(halved.algo_state.population)
    for dst, src in enumerate([0, 0, 2, 2]):
        np.testing.assert_array_equal(new_pop[dst], pop[src])
