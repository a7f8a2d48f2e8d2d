"""Islands and successive halving (:mod:`jaxpose.search.islands`)."""

from __future__ import annotations

import dataclasses

import jax
import numpy as np
from search_cases import GA_PLAIN, skeleton, spider_cloud

from jaxpose.search import FitConfig, Fitter
from jaxpose.search.islands import halve_islands, halving_generations

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
    halved = halve_islands(HALVING.static(), st)
    kept = halve_islands(plain.static(), st)
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
