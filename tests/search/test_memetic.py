"""Refinement inside the search (:mod:`jaxpose.search.memetic`)."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from search_cases import GA, branchy_skeleton, descendants, skeleton, spider_cloud

import jaxpose
from jaxpose.search import Fitter, memetic
from jaxpose.search.compiled import generations_jit
from jaxpose.search.loop import search_finish


def test_ga_final_refinement_candidates_are_distinct(monkeypatch):
    fitter = Fitter(skeleton(), GA)  # the programs run(GA) compiled
    st = fitter.init(spider_cloud(), jax.random.key(0))
    hists = []
    for length in fitter.epoch_lengths:
        st, h = fitter.step(st, length)
        hists.append(h)
    seen = []

    def spy(loss_fn, genomes, steps, learning_rate):
        seen.append(np.asarray(genomes))
        return genomes, jnp.full(genomes.shape[:1], jnp.inf)

    monkeypatch.setattr(memetic, "refine", spy)
    # eager: the spy sees concrete genomes
    search_finish(spider_cloud(), skeleton(), GA.static(), st, jnp.concatenate(hists))
    (cand,) = seen
    assert cand.shape[0] == min(GA.final_refine_top, GA.population)
    assert len(np.unique(cand, axis=0)) == cand.shape[0], "duplicate refinement candidates"


# --------------------------------------------------------------------------- limb hops


def _gene_names(skel):
    return jaxpose.genome_layout(skel).names


@pytest.mark.parametrize("make", [lambda: skeleton("humanoid"), branchy_skeleton], ids=["humanoid", "branchy"])
def test_hop_masks_are_each_subtrees_joint_angles_and_the_root_orientation(make):
    skel = make()
    names = _gene_names(skel)
    masks = memetic.hop_masks(skel)
    assert masks.shape == (skel.num_links + 1, len(names))
    for k in range(skel.num_links):  # oracle: the parent list and the gene names
        links = {skel.link_names[i] for i in descendants(skel, k)}
        want = [n.rsplit(".", 1)[0] in links and ".q" in n for n in names]
        assert masks[k].tolist() == want, skel.link_names[k]
    assert [n for n, m in zip(names, masks[-1]) if m] == ["root_roll", "root_pitch", "root_yaw"]


def test_limb_hops_redraw_one_mask_each_within_bounds():
    skel = skeleton("humanoid")
    masks = memetic.hop_masks(skel)
    genome = jnp.full((len(_gene_names(skel)),), 0.5, jnp.float32)
    hops = np.asarray(memetic.limb_hops(skel, jax.random.key(3), genome, 400))
    changed = hops != 0.5
    assert ((hops >= 0) & (hops < 1)).all()
    which = set()
    for row in changed:  # every changed gene lies in one mask, and (almost surely) all of its genes change
        fits = [k for k, m in enumerate(masks) if (row == m).all()]
        assert len(fits) == 1, np.flatnonzero(row)
        which.add(fits[0])
    assert len(which) == len(masks)  # 400 draws over 18 choices reach every one


@pytest.mark.slow  # limb hops are off by default (measured without gain): out of the suite's time
def test_memetic_hops_take_the_worst_rows_and_never_worsen_the_best():
    cfg = dataclasses.replace(GA, memetic_top=2, memetic_hops=3, final_refine_top=2, final_hops=2)
    assert cfg.memetic_rows == (2, 3) and cfg.final_rows == (2, 2)
    assert dataclasses.replace(cfg, memetic_hops=100).memetic_rows == (2, GA.population - 2)
    static = cfg.validate().static()
    fitter = Fitter(skeleton(), cfg)
    st = fitter.init(spider_cloud(), jax.random.key(0))
    st, _ = generations_jit(skeleton(), static, st, 2)
    before = np.asarray(st.algo_state.fitness)
    order, g, f = memetic.refine_top(skeleton(), static, st, cfg.memetic_rows, jnp.int32(2))
    ranked = np.argsort(before)
    assert np.asarray(order).tolist() == ranked[:2].tolist() + ranked[::-1][:3].tolist()
    after, _ = memetic.memetic_apply(skeleton(), static, st, (order, g, f), jnp.zeros(2))
    assert float(after.algo_state.best_fitness) <= float(st.algo_state.best_fitness)
    assert int(after.gradient_evaluations - st.gradient_evaluations) == 5 * cfg.memetic_steps
    # the rows neither refined nor hopped are untouched
    rest = np.setdiff1d(np.arange(GA.population), np.asarray(order))
    np.testing.assert_array_equal(np.asarray(after.algo_state.population)[rest],
                                  np.asarray(st.algo_state.population)[rest])
