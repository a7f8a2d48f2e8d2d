"""No recompilation between generations, or between images of the same padded size.

The fit is compiled in pieces (``search_init``, ``search_generations``, the
refinement ``refine_top`` shared by the memetic step and the final polish,
``memetic_apply``, ``search_result``; see :class:`jaxpose.search.Fitter`).  A
second cloud with the same ``max_points`` (any number of valid points) and the
same config must reuse all of them, the generations must be compiled once for all
the epochs of a fit, and the refinement once for the memetic steps and the final
one when they refine as many candidates.  Compilations are counted with a ``jax.monitoring`` listener on XLA's
backend-compile event (it fires once per executable built, cached or not), so
the checks hold whatever other tests compiled before.  No timing assertions.

A tiny two-link skeleton with a name and population no other test uses keeps the
compile short and makes sure the first fit really compiles.
"""

from __future__ import annotations

import contextlib
import importlib

import jax
import numpy as np
import pytest

from jaxpose.camera import points_to_cloud
from jaxpose.search import FitConfig, Fitter
from jaxpose.skeleton import LinkSpec, build_skeleton

# the module, not the function ``jaxpose.search.fit`` that shadows it
fit_module = importlib.import_module("jaxpose.search.fit")

BACKEND_COMPILE_EVENT = "/jax/core/compile/backend_compile_duration"
MAX_POINTS = 96
GENERATIONS, EPOCH = 6, 2  # three epochs of equal length: one epoch executable


@contextlib.contextmanager
def count_compiles():
    """Collect the names of the functions XLA compiles inside the block."""
    names: list[str] = []

    def listener(event, duration, **kwargs):
        if event == BACKEND_COMPILE_EVENT:
            names.append(str(kwargs.get("fun_name", "?")))

    jax.monitoring.register_event_duration_secs_listener(listener)
    try:
        yield names
    finally:
        jax.monitoring.unregister_event_duration_listener(listener)


@pytest.fixture(scope="module")
def skeleton():
    links = [
        LinkSpec("recompile_a", joint="ball", limits=[[-30, 30]] * 3, length=0.2, radius=0.02),
        LinkSpec("recompile_b", parent="recompile_a", joint="hinge", limits=[[-60, 60]], length=0.15,
                 length_range=(0.1, 0.2), radius=0.015),
    ]
    return build_skeleton("recompile_probe", links)


def cloud(seed: int, n_valid: int):
    """A noisy bent stick ~1.5 m in front of the camera, padded to MAX_POINTS."""
    rng = np.random.default_rng(seed)
    t = rng.uniform(0, 1, n_valid)
    pts = np.stack([0.3 * t - 0.1, 0.1 * np.sin(3 * t), 1.5 + 0.05 * t], -1)
    pts = pts + 0.01 * rng.standard_normal(pts.shape)
    c = points_to_cloud(pts, MAX_POINTS, seed)
    assert c.points.shape == (MAX_POINTS, 3)
    return c


def config(**kw) -> FitConfig:
    # memetic and final refinement (gradients through the cost) off: they only add compile time here
    base = dict(population=7, generations=GENERATIONS, chunk=EPOCH, memetic_every=0, final_refine_steps=0)
    base.update(kw)
    return FitConfig(**base)


def test_same_padded_size_does_not_recompile(skeleton):
    cfg = config()
    assert cfg.epoch == EPOCH and GENERATIONS % EPOCH == 0
    fitter = Fitter(skeleton, cfg)
    epochs_seen = []

    with count_compiles() as first:
        r1 = fitter.run(cloud(0, 80), jax.random.key(0), progress=lambda g, c, e: epochs_seen.append(g))
    assert epochs_seen == [2, 4, 6]
    # the counter works: this config is new to the process, so the first fit compiled
    assert first, "the first fit compiled nothing: is the compile listener still firing?"
    epoch_compiles = [n for n in first if "search_generations" in n]
    assert len(epoch_compiles) == 1, f"epoch compiled {len(epoch_compiles)} times for 3 epochs: {first}"
    # compiled ahead of the fit (compile_pieces), once, and kept for the next fit of this signature
    assert sum("search_init" in n for n in first) == 1, first
    assert fit_module._signature(cloud(0, 80), skeleton, jax.random.key(0), cfg) in fit_module._PROGRAMS

    # another image of the same padded size: other points, other number of valid points, other seed
    with count_compiles() as second:
        r2 = Fitter(skeleton, cfg).run(cloud(1, 57), jax.random.key(1))
    assert second == [], f"recompiled for a cloud of the same padded size: {second}"
    assert np.isfinite(float(r1.cost)) and np.isfinite(float(r2.cost))
    assert int(r2.objective_evaluations) == int(r1.objective_evaluations)

    # and a third, through the convenience wrapper
    with count_compiles() as third:
        fit_module.fit_cloud(cloud(2, MAX_POINTS), skeleton, seed=3, config=cfg)
    assert third == [], f"recompiled in fit_cloud: {third}"


def test_memetic_and_final_refinement_share_one_program(skeleton):
    # memetic on, and the final refinement refines as many candidates (steps differ)
    cfg = config(memetic_every=EPOCH, memetic_top=3, memetic_steps=2, final_refine_top=3, final_refine_steps=5,
                 population=9, islands=1)
    with count_compiles() as first:
        r1 = Fitter(skeleton, cfg).run(cloud(0, 80), jax.random.key(0))
    refine_compiles = [n for n in first if "refine_top" in n]
    assert len(refine_compiles) == 1, f"refinement compiled {len(refine_compiles)} times: {first}"
    # the counts say every refinement ran: 3 memetic steps and the final one, 3 candidates each
    assert int(r1.gradient_evaluations) == 3 * (3 * 2) + 3 * 5
    with count_compiles() as second:
        Fitter(skeleton, cfg).run(cloud(1, 61), jax.random.key(1))
    assert second == [], f"recompiled for a cloud of the same padded size: {second}"


def test_fast_compile_options_change_no_number(skeleton):
    """The refinement compiled with ``fast_compile_options`` (as are init, write-back
    and result) gives what XLA's default options give, up to float32 round-off
    (other kernels may sum in another order)."""
    from jaxpose._xla_flags import fast_compile_options

    cfg = config(memetic_every=EPOCH, memetic_top=3, memetic_steps=2, population=9, islands=2)
    st = fit_module._init_jit(cloud(4, 80), skeleton, jax.random.key(5), cfg)
    st, _ = fit_module._generations_jit(skeleton, cfg, st, EPOCH)
    plain_refine = jax.jit(fit_module.refine_top, static_argnames=("config", "m"))
    got = fit_module._refine_jit(skeleton, cfg, st, 3, np.int32(4))
    want = plain_refine(skeleton, cfg, st, 3, np.int32(4))
    np.testing.assert_array_equal(np.asarray(got[0]), np.asarray(want[0]))  # the same candidates
    # the refined costs agree to round-off; the genomes only to a few Adam steps: along a
    # direction the cost hardly depends on, Adam's normalised step turns a round-off-sized
    # gradient into a step of the learning rate, either way (0.018 after 4 steps was seen
    # on one machine, 0 on another)
    np.testing.assert_allclose(np.asarray(got[2]), np.asarray(want[2]), rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(np.asarray(got[1]), np.asarray(want[1]), rtol=0, atol=4 * cfg.learning_rate)
    before = np.take_along_axis(np.asarray(st.algo_state.population), np.asarray(got[0])[..., None], 1)
    assert not np.allclose(np.asarray(got[1]), before)  # the refinement moved the candidates
    assert fast_compile_options() is None or fit_module._once == fast_compile_options()


def test_pieces_compiled_ahead_give_what_the_jit_pieces_give(skeleton):
    """``Fitter`` runs the pieces ``compile_pieces`` compiled ahead of time (in worker
    threads); stepping the ``_*_jit`` functions by hand gives the same fit bit for
    bit.  (The config is the one above, whose jit pieces are compiled already.)"""
    cfg = config(memetic_every=EPOCH, memetic_top=3, memetic_steps=2, population=9, islands=2)
    c, key = cloud(6, 80), jax.random.key(7)
    got = Fitter(skeleton, cfg).run(c, key)
    st = fit_module._init_jit(c, skeleton, key, cfg)
    hists = []
    for _ in range(GENERATIONS // EPOCH):
        st, h = fit_module._epoch_jit(skeleton, cfg, st, EPOCH)
        hists.append(h)
    want = fit_module._finish_jit(c, skeleton, cfg, st, jax.numpy.concatenate(hists))
    for name in ("genome", "cost", "history", "objective_evaluations", "gradient_evaluations"):
        np.testing.assert_array_equal(np.asarray(getattr(got, name)), np.asarray(getattr(want, name)), err_msg=name)
    # a memetic step after each of the three epochs: 2 islands x 3 candidates x 2 steps
    assert int(got.gradient_evaluations) == 3 * (2 * 3 * 2)
