"""The search as compiled programs (:mod:`jaxpose.search.compiled`): no recompilation
between epochs, between images of the same padded size, or between settings that
are traced (:class:`~jaxpose.search.FitParams`).

A fit is compiled in programs (``search_init``, ``search_generations``, the
refinement ``refine_top`` shared by the memetic step and the final polish,
``memetic_apply``, ``search_result``; see :class:`jaxpose.search.Fitter`).  A
second cloud with the same padded size (any number of valid points) and the same
static config must reuse all of them, the generations must be compiled once for all
the epochs of a fit, and the refinement once for the memetic steps and the final
one when they refine as many candidates.  Compilations are counted with
:func:`search_cases.count_compiles`.  No timing assertions.

Probe skeletons with names no other test uses keep the compiles short and make sure
the first fit really compiles.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from search_cases import PROBE_POINTS, count_compiles, probe_cloud, probe_skeleton

from jaxpose import ObjectiveConfig, decode, forward_kinematics, observe, population_cost
from jaxpose.errors import ConfigError
from jaxpose.kinematics import collision_pairs
from jaxpose.search import FitConfig, Fitter, fit_cloud
from jaxpose.search.compiled import (
    JIT_STEPS,
    PROGRAMS,
    as_float32,
    generations_jit,
    init_jit,
    refine_jit,
    result_jit,
    signature,
)
from jaxpose.search.loop import search_epoch
from jaxpose.search.memetic import final_refine, refine_top
from jaxpose.skeleton import LinkSpec, build_skeleton

GENERATIONS, EPOCH = 6, 2  # three epochs of equal length: one epoch executable


@pytest.fixture(scope="module")
def skeleton():
    return probe_skeleton()


def config(**kw) -> FitConfig:
    # memetic and final refinement (gradients through the cost) off: they only add compile time here
    # one search unless a test asks for the portfolio; no limb sweep (on a search this short it does most of
    # the work and turns round-off between programs into different answers: docs/search.md, "Limb sweep")
    base = dict(population=7, generations=GENERATIONS, epoch=EPOCH, memetic_steps=0, final_refine_steps=0,
                staged_alternatives=(), turns=0, limb_sweep=0, pivot_sweep=0)
    base.update(kw)
    return FitConfig(**base)


def test_same_padded_size_does_not_recompile(skeleton):
    cfg = config(staged_alternatives=(0.0,))  # FitConfig's default portfolio: two searches, one set of programs
    assert cfg.epoch == EPOCH and GENERATIONS % EPOCH == 0
    fitter = Fitter(skeleton, cfg)
    epochs_seen = []

    with count_compiles() as first:
        r1 = fitter.run(probe_cloud(0, 80), jax.random.key(0), progress=lambda g, c, e: epochs_seen.append(g))
    assert epochs_seen == [2, 4, 6, 8, 10, 12]  # the second search's generations follow the first's
    # the counter works: this config is new to the process, so the first fit compiled
    assert first, "the first fit compiled nothing: is the compile listener still firing?"
    epoch_compiles = [n for n in first if "search_generations" in n]
    assert len(epoch_compiles) == 1, f"epoch compiled {len(epoch_compiles)} times for 2 x 3 epochs: {first}"
    # compiled ahead of the fit (compile_search), once, and kept for the next fit of this signature
    assert sum("search_init" in n for n in first) == 1, first
    sig = signature(as_float32(probe_cloud(0, 80)), skeleton, jax.random.key(0), cfg.static(), cfg.params())
    assert sig in PROGRAMS

    # another image of the same padded size: other points, other number of valid points, other seed
    with count_compiles() as second:
        r2 = Fitter(skeleton, cfg).run(probe_cloud(1, 57), jax.random.key(1))
    assert second == [], f"recompiled for a cloud of the same padded size: {second}"
    assert np.isfinite(float(r1.cost)) and np.isfinite(float(r2.cost))
    assert int(r2.objective_evaluations) == int(r1.objective_evaluations)

    # and a third, through the convenience wrapper
    with count_compiles() as third:
        fit_cloud(probe_cloud(2, PROBE_POINTS), skeleton, seed=3, config=cfg)
    assert third == [], f"recompiled in fit_cloud: {third}"


def test_memetic_and_final_refinement_share_one_program(skeleton):
    # memetic on, and the final refinement refines as many candidates (steps differ)
    cfg = config(memetic_top=3, memetic_steps=2, final_refine_top=3, final_refine_steps=5, population=9, islands=1)
    with count_compiles() as first:
        r1 = Fitter(skeleton, cfg).run(probe_cloud(0, 80), jax.random.key(0))
    refine_compiles = [n for n in first if "refine_top" in n]
    assert len(refine_compiles) == 1, f"refinement compiled {len(refine_compiles)} times: {first}"
    # the counts say every refinement ran: 3 memetic steps and the final one, 3 candidates each
    assert int(r1.gradient_evaluations) == 3 * (3 * 2) + 3 * 5
    with count_compiles() as second:
        Fitter(skeleton, cfg).run(probe_cloud(1, 61), jax.random.key(1))
    assert second == [], f"recompiled for a cloud of the same padded size: {second}"


def test_fast_compile_options_change_no_number(skeleton):
    """The refinement compiled with ``fast_compile_options`` (as are init, write-back
    and result) gives what XLA's default options give, up to float32 round-off
    (other kernels may sum in another order)."""
    from jaxpose._xla_flags import fast_compile_options

    cfg = config(memetic_top=3, memetic_steps=2, population=9, islands=2)
    static = cfg.static()
    st = init_jit(probe_cloud(4, 80), skeleton, jax.random.key(5), config=static, params=cfg.params())
    st, _ = generations_jit(skeleton, static, st, EPOCH)
    # XLA's default emitters against the fast ones, also where the suite turns them off (tests/xla_settings.py)
    default = None if fast_compile_options() is None else {k: not v for k, v in fast_compile_options().items()}
    plain_refine = jax.jit(refine_top, static_argnames=("config", "m"), compiler_options=default)
    got = refine_jit(skeleton, static, st, 3, np.int32(4))
    want = plain_refine(skeleton, static, st, 3, np.int32(4))
    np.testing.assert_array_equal(np.asarray(got[0]), np.asarray(want[0]))  # the same candidates
    # the refined costs agree to round-off; the genomes only to a few Adam steps: along a
    # direction the cost hardly depends on, Adam's normalised step turns a round-off-sized
    # gradient into a step of the learning rate, either way (0.018 after 4 steps was seen
    # on one machine, 0 on another)
    np.testing.assert_allclose(np.asarray(got[2]), np.asarray(want[2]), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(np.asarray(got[1]), np.asarray(want[1]), rtol=0, atol=4 * cfg.learning_rate)
    before = np.take_along_axis(np.asarray(st.algo_state.population), np.asarray(got[0])[..., None], 1)
    assert not np.allclose(np.asarray(got[1]), before)  # the refinement moved the candidates
    # the refinement really is compiled with those options: the same executable as a jit of
    # refine_top given them (the optimised program's text)
    if fast_compile_options() is not None:
        fast_refine = jax.jit(refine_top, static_argnames=("config", "m"), compiler_options=fast_compile_options())
        args = (skeleton, static, st, 3, np.int32(4))
        text = lambda f: f.lower(*args).compile().as_text()
        assert text(refine_jit) == text(fast_refine)


def test_programs_compiled_ahead_give_what_the_jit_programs_give(skeleton):
    """``Fitter`` runs the programs ``compile_search`` compiled ahead of time (in worker
    threads); stepping the ``*_jit`` functions by hand gives the same fit bit for
    bit.  (The config is the one above, whose jit programs are compiled already.)"""
    cfg = config(memetic_top=3, memetic_steps=2, population=9, islands=2)
    static = cfg.static()
    c, key = probe_cloud(6, 80), jax.random.key(7)
    got = Fitter(skeleton, cfg).run(c, key)
    st = init_jit(c, skeleton, key, config=static, params=cfg.params())
    hists = []
    for _ in range(GENERATIONS // EPOCH):
        st, h = search_epoch(skeleton, static, st, EPOCH, JIT_STEPS)
        hists.append(h)
    want = result_jit(c, skeleton, static, st, jnp.concatenate(hists), final_refine(skeleton, static, st, refine_jit))
    for name in ("genome", "cost", "history", "objective_evaluations", "gradient_evaluations"):
        np.testing.assert_array_equal(np.asarray(getattr(got, name)), np.asarray(getattr(want, name)), err_msg=name)
    # a memetic step after each of the three epochs: 2 islands x 3 candidates x 2 steps
    assert int(got.gradient_evaluations) == 3 * (2 * 3 * 2)


# --------------------------------------------------------------------------- a sweep over traced settings


def sweep_skeleton():
    """Three links in a chain: the first and the last make a collision pair (a folded
    hinge brings them together)."""
    links = [
        LinkSpec("sweep_a", joint="ball", limits=[[-30, 30]] * 3, length=0.2, radius=0.02),
        LinkSpec("sweep_b", parent="sweep_a", joint="hinge", limits=[[-90, 90]], length=0.06, radius=0.02),
        LinkSpec("sweep_c", parent="sweep_b", joint="hinge", limits=[[-170, 170]], length=0.15,
                 length_range=(0.1, 0.2), radius=0.02),
    ]
    return build_skeleton("sweep_probe", links)


# memetic step and final refinement on (learning_rate reaches them), 3 elites (crossover
# mixes two of them), no per-gene mutation (mutation_rate 1 is another search)
SWEEP = FitConfig(population=12, generations=GENERATIONS, epoch=EPOCH, memetic_top=3, memetic_steps=2,
                  final_refine_top=3, final_refine_steps=2, islands=1, mutation_rate=0.0,
                  turns=0, objective=ObjectiveConfig(free_space_weight=3.0))
# every traced setting changed
SWEEP_ALL = dataclasses.replace(
    SWEEP, crossover_rate=0.9, mutation_rate=0.5, branch_mutation_rate=0.8, branch_reset_rate=0.5,
    learning_rate=0.05, objective=dataclasses.replace(SWEEP.objective, sigma_factor=0.5, free_space_weight=1.0,
                                                      collision_weight=0.02))


def sweep_costs(skel, cloud, objective, st):
    """The objective ``(P,)`` of every individual of ``st``'s population, straight from
    ``jaxpose.objective`` (collision pairs included) with ``objective``'s sigma and weights."""
    return np.asarray(_sweep_costs(skel, cloud, objective.sigma_factor, objective.free_space_weight,
                                   objective.collision_weight, st))


@jax.jit
def _sweep_costs(skel, cloud, sigma_factor, free_space_weight, collision_weight, st):
    # one compile for every weight: the weights are arguments (all positive: every term is in)
    objective = dataclasses.replace(SWEEP.objective, sigma_factor=sigma_factor)
    poses = jax.vmap(lambda g: decode(skel, st.bounds, g))(st.algo_state.population)
    links = jax.vmap(lambda p: forward_kinematics(skel, p))(poses)
    pairs = collision_pairs(skel, objective.collision_margin)
    return population_cost(observe(cloud, objective), links.start, links.end, links.radius, objective, pairs=pairs,
                           weights=(free_space_weight, collision_weight))


def sweep_fit(skel, cloud, config):
    """A whole fit, stepped: ``(final state, result)``."""
    fitter = Fitter(skel, config)
    st, hists = fitter.init(cloud, jax.random.key(0)), []
    for length in fitter.epoch_lengths:
        st, h = fitter.step(st, length)
        hists.append(h)
    return st, fitter.finish(st, jnp.concatenate(hists))


def test_a_sweep_over_rates_and_weights_compiles_once():
    """Configs that differ only in traced settings (GA rates, learning rate, sigma and
    positive weights) share one compiled search, and the settings reach it."""
    skel, cloud = sweep_skeleton(), as_float32(probe_cloud(0, 80))
    PROGRAMS.entries.clear()  # the first fit compiles, whatever ran before
    configs = [SWEEP, SWEEP_ALL, dataclasses.replace(SWEEP, mutation_rate=1.0)]
    results, compiles = [], []
    for cfg in configs:
        with count_compiles() as names:
            results.append(fit_cloud(cloud, skel, 0, cfg))
        compiles.append(names)
    assert compiles[0], "the first fit compiled nothing: is the compile listener still firing?"
    assert compiles[1:] == [[], []], f"a sweep over traced settings recompiled: {compiles[1:]}"
    genomes = [np.asarray(r.genome) for r in results]
    assert not np.array_equal(genomes[0], genomes[2]), "mutation_rate 0 and 1 gave the same fit"
    assert not np.array_equal(genomes[0], genomes[1]) and not np.array_equal(genomes[1], genomes[2])


TRACED_VARIANTS = {
    "crossover_rate": {"crossover_rate": 0.9},
    "mutation_rate": {"mutation_rate": 1.0},
    "branch_mutation_rate": {"branch_mutation_rate": 0.9},
    "branch_reset_rate": {"branch_reset_rate": 0.8},
    "learning_rate": {"learning_rate": 0.1},
    "init_root_std": {"init_root_std": 1.0},
    "init_pca_std": {"init_pca_std": 0.2},
    "sigma_factor": {"objective": dataclasses.replace(SWEEP.objective, sigma_factor=0.5)},
    "free_space_weight": {"objective": dataclasses.replace(SWEEP.objective, free_space_weight=1.0)},
    "collision_weight": {"objective": dataclasses.replace(SWEEP.objective, collision_weight=0.02)},
}


def test_every_traced_setting_reaches_the_compiled_search():
    """Each traced setting alone, changed: nothing compiles and the search goes
    otherwise (its initial population, its population at the end, or its result);
    the population's costs are the objective with that config's weights, recomputed
    from scratch (not the first config's, which the programs were compiled with)."""
    skel, cloud = sweep_skeleton(), as_float32(probe_cloud(0, 80))
    base_st, base = sweep_fit(skel, cloud, SWEEP)
    np.testing.assert_allclose(np.asarray(base_st.algo_state.fitness),
                               sweep_costs(skel, cloud, SWEEP.objective, base_st), rtol=1e-5)
    for name, change in TRACED_VARIANTS.items():
        cfg = dataclasses.replace(SWEEP, **change)
        with count_compiles() as names:
            st, res = sweep_fit(skel, cloud, cfg)
        assert names == [], f"{name}: recompiled {names}"
        differs = [not np.array_equal(np.asarray(a), np.asarray(b)) for a, b in [
            (st.initial, base_st.initial), (st.algo_state.population, base_st.algo_state.population),
            (res.genome, base.genome), (res.cost, base.cost)]]
        assert any(differs), f"{name}: the same search as the first config"
        fitness = np.asarray(st.algo_state.fitness)
        np.testing.assert_allclose(fitness, sweep_costs(skel, cloud, cfg.objective, st), rtol=1e-5, err_msg=name)
        if "objective" in change:  # the weight matters for this population: the check above has teeth
            assert not np.allclose(fitness, sweep_costs(skel, cloud, SWEEP.objective, st), rtol=1e-5), name


def test_stepping_a_fitter_by_hand_is_refused_clearly_when_misused():
    skel = probe_skeleton()
    fitter = Fitter(skel, config())
    with pytest.raises(RuntimeError, match="call init"):
        fitter.finish(None, None)
    st = fitter.init(probe_cloud(0, 80), jax.random.key(0))
    with pytest.raises(ConfigError, match="epochs are"):
        fitter.step(st, fitter.epoch_lengths[0] + 1)
    with pytest.raises(ConfigError, match="static"):
        Fitter(skel, config().static())
