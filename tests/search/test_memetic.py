"""Refinement inside the search (:mod:`jaxpose.search.memetic`)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from search_cases import GA, skeleton, spider_cloud

from jaxpose.search import Fitter, memetic
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
