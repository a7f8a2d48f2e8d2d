"""Which genes are searched when (:mod:`jaxpose.search.genes`): staged search, tied lengths."""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np
import pytest
from search_cases import GA, branchy_skeleton, run, skeleton

from jaxpose import genome_layout
from jaxpose.metrics import link_orbits
from jaxpose.search.genes import tie_lengths, unlocked


def test_tie_lengths_gives_alike_links_one_length():
    """tie_lengths: the spider's four upper and four lower legs each end with one length
    (through the initial population, children, memetic steps and the final refinement);
    without it they differ."""
    skel = skeleton()
    orbits = [o for o in link_orbits(skel) if len(o) > 1]
    assert orbits  # the oracle: the metrics' symmetry groups
    tied = np.asarray(run(dataclasses.replace(GA, tie_lengths=True)).pose.lengths)
    free = np.asarray(run(GA).pose.lengths)
    for o in orbits:
        assert np.all(tied[list(o)] == tied[o[0]]), [skel.link_names[i] for i in o]
    assert any(np.ptp(free[list(o)]) > 1e-4 for o in orbits)


@pytest.mark.parametrize("name", ["spider", "humanoid", "arm7"])
def test_tie_sets_the_length_genes_of_each_orbit_to_their_mean(name):
    skel = skeleton(name)
    layout = genome_layout(skel)
    g = np.random.default_rng(0).uniform(size=(5, layout.size)).astype(np.float32)
    tied = np.asarray(tie_lengths(skel, jnp.asarray(g)))
    want = g.copy()  # oracle: a loop over the orbits and their length genes by name
    for o in link_orbits(skel):
        idx = [layout.names.index(f"{skel.link_names[i]}.length") for i in o
               if f"{skel.link_names[i]}.length" in layout.names]
        want[:, idx] = g[:, idx].mean(1, keepdims=True)
    np.testing.assert_allclose(tied, want, rtol=1e-6)
    assert np.array_equal(np.asarray(tie_lengths(skel, jnp.asarray(tied))), tied)  # a projection
    changed = not np.array_equal(tied, g)
    assert changed == (name != "arm7")  # the arm has no alike links


def depth(parents, k):
    """Links above ``k`` (0 for a root link), by walking up."""
    d = 0
    while parents[k] >= 0:
        k, d = parents[k], d + 1
    return d


@pytest.mark.parametrize("name", ["spider", "humanoid", "branchy"])
def test_staged_search_unlocks_the_tree_level_by_level(name):
    """FitConfig.staged: links at depth d join after d / levels of the staged phase
    (``staged * generations``); the root genes are searched from the start; staged 0: all at once."""
    skel = branchy_skeleton() if name == "branchy" else skeleton(name)
    link_of = np.asarray(genome_layout(skel).link_of_gene)
    depths = np.array([depth(skel.parents, k) for k in range(skel.num_links)])
    levels = depths.max() + 1
    config = dataclasses.replace(GA, generations=120, staged=0.5)
    phase = 0.5 * 120 / levels
    for generation in range(0, 121, 5):
        want = (link_of < 0) | (depths[np.maximum(link_of, 0)] <= generation // phase)
        np.testing.assert_array_equal(np.asarray(unlocked(skel, config, generation)), want, err_msg=str(generation))
    assert np.all(np.asarray(unlocked(skel, config, 60)))  # the staged phase over: everything
    assert np.all(np.asarray(unlocked(skel, dataclasses.replace(config, staged=0.0), 0)))
