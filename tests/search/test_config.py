"""The search's settings (:mod:`jaxpose.search.config`): validation, the automatic
number of generations, epochs, and the split into a static config and traced
:class:`~jaxpose.search.FitParams`."""

from __future__ import annotations

import dataclasses

import jax
import numpy as np
import pytest
from search_cases import CMA, GA, GA_PLAIN, HC, OBJ, expected_counts, skeleton, spider_cloud

from jaxpose import genome_layout
from jaxpose.errors import ConfigError
from jaxpose.search import FitConfig, FitParams, Fitter, auto_generations, fit, fit_cloud
from jaxpose.search.loop import search_init

# FitConfig's docstring: "The rates, learning_rate, the initial spreads, staged and the
# objective's sigma_factor and positive weights are traced"
TRACED = ("crossover_rate", "mutation_rate", "branch_mutation_rate", "branch_reset_rate", "learning_rate",
          "init_root_std", "init_pca_std", "staged")
TRACED_OBJECTIVE = ("sigma_factor", "free_space_weight", "collision_weight")


@pytest.mark.parametrize("name, genes", [("spider", 7 + 8 * 4), ("humanoid", 75), ("arm7", 21), ("snake", 47)])
def test_default_generations_are_chosen_per_skeleton(name, genes):
    """generations=None (the default): 4 per searched gene within 100..300, rounded to whole
    epochs (FitConfig's docstring); the gene counts are the skeleton files' documented DOF."""
    skel = skeleton(name)
    assert genome_layout(skel).size == genes
    want = {"spider": 150, "humanoid": 300, "arm7": 100, "snake": 200}[name]  # 156, 300, 84 -> 100, 188
    assert want == 25 * round(min(300, max(100, 4 * genes)) / 25)
    assert FitConfig().generations is None
    assert auto_generations(skel) == want
    assert FitConfig().for_skeleton(skel).generations == want
    # GA's epoch is 2 generations: whole epochs of 2
    g2 = 2 * round(min(300, max(100, 4 * genes)) / 2)
    assert Fitter(skel, dataclasses.replace(GA, generations=None)).config == dataclasses.replace(GA, generations=g2)
    assert dataclasses.replace(GA, generations=7).for_skeleton(skel).generations == 7  # explicit: kept


def test_pure_fit_resolves_the_generations_while_tracing():
    """jit(fit) with generations=None traces a fit of the skeleton's automatic count (lowered, not compiled)."""
    config = dataclasses.replace(GA, generations=None)
    low = jax.jit(fit, static_argnames="config").lower(spider_cloud(), skeleton(), jax.random.key(0), config=config)
    assert low.out_info.history.shape == (156,)  # 4 x 39 genes, in whole epochs of GA's 2 generations


def test_search_pieces_want_resolved_generations():
    config = dataclasses.replace(GA, generations=None)
    with pytest.raises(ConfigError, match="for_skeleton"):
        search_init(spider_cloud(), skeleton(), jax.random.key(0), config.static(), config.params())


@pytest.mark.parametrize("bad", [
    dict(population=1), dict(population=0), dict(population=8.0), dict(generations=0), dict(generations=-3),
    dict(algorithm="no_such_algorithm"), dict(islands=0), dict(tie_lengths="yes"), dict(epoch=0),
])
def test_config_errors(bad):
    config = dataclasses.replace(GA, **bad)
    with pytest.raises(ConfigError):
        config.validate()
    with pytest.raises(ConfigError):
        Fitter(skeleton(), config)
    with pytest.raises(ConfigError):
        fit_cloud(spider_cloud(), skeleton(), 0, config)
    with pytest.raises(ConfigError):  # raised while tracing, before any compile
        jax.jit(fit, static_argnames="config")(spider_cloud(), skeleton(), jax.random.key(0), config)


def test_halve_islands_at_must_hold_fractions():
    with pytest.raises(ConfigError, match="halve_islands_at"):
        FitConfig(halve_islands_at=(0.5, 1.0)).validate()
    assert FitConfig(halve_islands_at=[0.25]).halve_islands_at == (0.25,)  # lists become tuples (hashable)


def test_coarse_to_fine_is_for_the_ga_only():
    with pytest.raises(ConfigError, match=r"the GA \(algorithm 'ga'\) only"):
        dataclasses.replace(HC, coarse_points=10).validate()


def test_population_based_evosax_strategy_runs_or_is_refused():
    config = dataclasses.replace(CMA, algorithm="pso", population=8, generations=2, epoch=2)
    try:
        res = fit_cloud(spider_cloud(), skeleton(), 0, config)
    except ConfigError:
        return  # refused up front: acceptable
    assert int(res.objective_evaluations) == expected_counts(config)[0]


# --------------------------------------------------------------------------- epochs


def test_epoch_lengths_cover_the_generations_in_whole_epochs_and_one_shorter():
    assert dataclasses.replace(GA, generations=4, epoch=2).epoch_lengths == (2, 2)
    assert dataclasses.replace(GA, generations=5, epoch=2).epoch_lengths == (2, 2, 1)
    assert dataclasses.replace(GA, generations=3, epoch=25).epoch_lengths == (3,)
    assert Fitter(skeleton(), GA).epoch_lengths == (2, 2)


def test_memetic_and_final_refinement_switches_and_counts():
    """The memetic step is on for the GA when memetic_top and memetic_steps are both
    positive; it and the final refinement refine at most the population (the final
    one only the best point of the other algorithms)."""
    assert GA.memetic_on and not GA_PLAIN.memetic_on
    assert not dataclasses.replace(GA, memetic_top=0).memetic_on
    assert not dataclasses.replace(HC, memetic_steps=10, memetic_top=4).memetic_on  # GA only
    assert (GA.memetic_count, GA.final_count) == (16, 16)  # 20 clamped to the population
    assert dataclasses.replace(GA, memetic_top=3, final_refine_top=5).memetic_count == 3
    assert HC.final_count == 1 and HC.final_refine_on
    assert not GA_PLAIN.final_refine_on and not dataclasses.replace(GA, final_refine_top=0).final_refine_on


# --------------------------------------------------------------------------- static and traced settings


def test_params_hold_the_traced_settings_as_float32():
    config = dataclasses.replace(GA, crossover_rate=0.3, learning_rate=0.02, init_pca_std=0.05,
                                 objective=dataclasses.replace(OBJ, sigma_factor=0.4, collision_weight=0.7))
    params = config.params()
    assert isinstance(params, FitParams)
    # and the turn searches' window (FitParams' docstring: no config field sets it), off
    assert sorted(f.name for f in dataclasses.fields(params)) == sorted(TRACED + TRACED_OBJECTIVE
                                                                        + ("root_rpy", "root_window"))
    for name in TRACED:
        assert params_value(params, name) == np.float32(getattr(config, name)), name
    for name in TRACED_OBJECTIVE:
        assert params_value(params, name) == np.float32(getattr(config.objective, name)), name
    assert params_value(params, "root_window") == 0
    assert np.asarray(params.root_rpy).shape == (3,) and np.asarray(params.root_rpy).dtype == np.float32


def params_value(params, name):
    v = np.asarray(getattr(params, name))
    assert v.shape == () and v.dtype == np.float32, name
    return v


def test_static_config_drops_the_traced_settings_only():
    config = dataclasses.replace(GA, mutation_rate=0.4, restarts=3,
                                 objective=dataclasses.replace(OBJ, free_space_weight=2.0))
    static = config.static()
    for name in TRACED:
        assert getattr(static, name) is None, name
    for name in TRACED_OBJECTIVE:
        assert getattr(static.objective, name) is None, name
    # everything else is kept
    # the turn searches (a traced window) and the restarts run the same programs: read from the full config only
    assert (static.turns, static.turn_window, static.restarts) == (0, None, 1)
    for f in dataclasses.fields(config):
        if f.name not in TRACED + ("objective", "turns", "turn_window", "restarts"):
            assert getattr(static, f.name) == getattr(config, f.name), f.name
    for f in dataclasses.fields(config.objective):
        if f.name not in TRACED_OBJECTIVE:
            assert getattr(static.objective, f.name) == getattr(config.objective, f.name), f.name
    # configs that differ only in traced settings share one static config (one compiled search)
    other = dataclasses.replace(config, crossover_rate=0.9, learning_rate=0.5,
                                objective=dataclasses.replace(config.objective, sigma_factor=1.0,
                                                              collision_weight=3.0))
    assert other.static() == static and hash(other.static()) == hash(static)
    assert dataclasses.replace(config, turns=3, turn_window=0.3, restarts=1).static() == static
    # ... but not one with another shape or schedule
    assert dataclasses.replace(config, population=9).static() != static


def test_a_zero_weight_is_static():
    """A weight of exactly 0 leaves its term out of the program: it stays in the static config."""
    off = dataclasses.replace(GA, objective=dataclasses.replace(OBJ, free_space_weight=0.0))
    assert off.static().objective.free_space_weight == 0.0
    assert off.static().objective.collision_weight is None
    assert off.static() != GA.static()
