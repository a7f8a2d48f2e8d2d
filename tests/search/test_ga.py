"""The branch-swap GA's operators (:mod:`jaxpose.search.ga`) on small genomes:
subtree masks, branch swap, mutation and branch reset, elitism and selection."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from search_cases import SHIPPED, branchy_skeleton, skeleton

from jaxpose import genome_layout
from jaxpose.search import BranchSwapGA, branch_swap, mutate, subtree_masks

# --------------------------------------------------------------------------- 1. subtree masks


def descendants(parents, k):
    """Links whose chain of parents reaches ``k`` (``k`` included), by walking up."""
    out = set()
    for j in range(len(parents)):
        i = j
        while i >= 0:
            if i == k:
                out.add(j)
                break
            i = parents[i]
    return out


@pytest.mark.parametrize("name", SHIPPED + ("branchy",))
def test_subtree_masks_cover_exactly_the_subtree_genes(name):
    skel = branchy_skeleton() if name == "branchy" else skeleton(name)
    layout = genome_layout(skel)
    link_of = np.asarray(layout.link_of_gene)
    masks = np.asarray(subtree_masks(skel))
    assert masks.shape == (skel.num_links, layout.size) and masks.dtype == bool
    for k in range(skel.num_links):
        want = np.isin(link_of, sorted(descendants(skel.parents, k)))
        np.testing.assert_array_equal(masks[k], want, err_msg=f"{name}: link {skel.link_names[k]}")
    assert not masks[:, link_of == -1].any(), "root genes must never be swapped or branch-mutated"
    assert (link_of == -1).sum() == 7


def test_branchy_skeleton_has_gene_less_links():
    # guards the fixture above: the "c" link (fixed joint, fixed length) has no genes of its own
    skel = branchy_skeleton()
    link_of = np.asarray(genome_layout(skel).link_of_gene)
    assert not (link_of == skel.index("c")).any()
    assert np.asarray(subtree_masks(skel))[skel.index("c")].sum() == (link_of == skel.index("d")).sum() + (
        link_of == skel.index("f")).sum()


# --------------------------------------------------------------------------- 2. branch swap

# one compile per mask shape, rates traced
_swap_batch = jax.jit(jax.vmap(branch_swap, in_axes=(0, None, None, None, None)))
_mutate_batch = jax.jit(jax.vmap(mutate, in_axes=(0, None, None, None, None, None)))


def _swap_many(masks, rate, n=400):
    D = masks.shape[1]
    keys = jax.random.split(jax.random.key(3), n)
    child = _swap_batch(keys, jnp.full((D,), 0.25), jnp.full((D,), 0.75), jnp.asarray(masks), jnp.float32(rate))
    return np.asarray(child)


@pytest.mark.parametrize("name", ["spider", "humanoid", "branchy"])
def test_branch_swap_rate_one_swaps_exactly_one_subtree(name):
    skel = branchy_skeleton() if name == "branchy" else skeleton(name)
    masks = np.asarray(subtree_masks(skel))
    child = _swap_many(masks, 1.0)
    assert set(np.unique(child)) <= {0.25, 0.75}
    seen = set()
    for row in child:
        differs = row != 0.25  # the parents differ in every gene
        hits = [k for k in range(len(masks)) if np.array_equal(differs, masks[k])]
        assert hits, f"child takes genes {np.flatnonzero(differs)} from parent 2: not one subtree"
        seen.update(hits)
    assert seen == set(range(len(masks))), "every subtree should be chosen sometimes"


def test_branch_swap_rate_zero_is_parent_one_and_rate_half_swaps_about_half():
    masks = np.asarray(subtree_masks(skeleton()))
    np.testing.assert_array_equal(_swap_many(masks, 0.0), 0.25)
    swapped = np.mean(np.any(_swap_many(masks, 0.5) != 0.25, axis=1))
    assert 0.38 < swapped < 0.62


# --------------------------------------------------------------------------- 3. mutation


def _mutate_many(x, std, rate, branch_rate, n=64, seed=0):
    masks = jnp.asarray(subtree_masks(skeleton()))
    keys = jax.random.split(jax.random.key(seed), n)
    f = jnp.float32
    return np.asarray(_mutate_batch(keys, jnp.asarray(x, f), f(std), f(rate), f(branch_rate), masks))


def test_mutate_stays_in_unit_box_from_the_corners():
    D = genome_layout(skeleton()).size
    x = (np.arange(D) % 2).astype(np.float32)  # genes at 0 and 1
    for rate, branch_rate in [(1.0, 0.0), (0.5, 0.5), (0.0, 1.0)]:
        y = _mutate_many(x, 1e3, rate, branch_rate)
        assert np.all(np.isfinite(y)) and y.min() >= 0.0 and y.max() <= 1.0, (rate, branch_rate)
        assert np.any(y != x), (rate, branch_rate)
        if rate == 1.0 and branch_rate == 0.0:
            # every gene mutated with a huge step: about half cross to the other side
            assert 0.3 < np.mean(y != x) < 0.7


def test_mutate_branch_mode_touches_one_subtree_only():
    masks = np.asarray(subtree_masks(skeleton()))
    x = np.full(masks.shape[1], 0.5, np.float32)
    for row in _mutate_many(x, 0.1, 0.0, 1.0, seed=1):
        changed = row != 0.5
        assert changed.any()
        assert any(not (changed & ~m).any() for m in masks), "branch mutation left its subtree"


def test_branch_reset_redraws_one_whole_subtree_uniformly():
    masks = np.asarray(subtree_masks(skeleton()))
    x = np.full(masks.shape[1], 0.5, np.float32)
    keys = jax.random.split(jax.random.key(3), 400)
    # no Gaussian mutation (rates 0): only the reset can move a gene
    rows = np.asarray(jax.vmap(lambda k: mutate(k, x, 0.1, 0.0, 0.0, jnp.asarray(masks), 1.0))(keys))
    moved = rows != 0.5
    for row in moved:
        assert any((row == m).all() for m in masks), "a reset must redraw exactly one subtree's genes"
    vals = rows[moved]
    assert vals.min() >= 0.0 and vals.max() <= 1.0
    # uniform on [0, 1]: mean 1/2, variance 1/12, both tails reached
    assert abs(vals.mean() - 0.5) < 0.03 and abs(vals.var() - 1 / 12) < 0.01
    assert vals.min() < 0.02 and vals.max() > 0.98
    # reset_rate 0 (and no other mutation) leaves the child untouched
    same = np.asarray(jax.vmap(lambda k: mutate(k, x, 0.1, 0.0, 0.0, jnp.asarray(masks), 0.0))(keys[:20]))
    np.testing.assert_array_equal(same, np.broadcast_to(x, same.shape))


def test_mutate_rate_zero_changes_nothing():
    x = np.asarray(jax.random.uniform(jax.random.key(2), (genome_layout(skeleton()).size,)))
    y = _mutate_many(x, 0.5, 0.0, 0.0)
    np.testing.assert_array_equal(y, np.broadcast_to(x, y.shape))


# --------------------------------------------------------------------------- 4. elitism and selection


def _ga(P=16, **kw):
    masks = subtree_masks(skeleton())
    algo = BranchSwapGA(P, jnp.zeros(masks.shape[1]), masks, **kw)
    return algo, algo.default_params


def test_ga_is_elitist_under_a_random_cost_with_failures():
    P = 16
    algo, params = _ga(P)
    key = jax.random.key(0)
    k0, k1, key = jax.random.split(key, 3)
    pop = jax.random.uniform(k0, (P, algo.num_dims))
    state = algo.init(k1, pop, jax.random.uniform(jax.random.key(9), (P,)), params)
    prev_best, prev_min = float(state.best_fitness), float(np.min(state.fitness))
    for gen in range(8):
        key, ka, kt, kf = jax.random.split(key, 4)
        children, state_a = algo.ask(ka, state, params)
        fitness = jax.random.uniform(kf, (P,))  # a fresh random cost: nothing to learn
        fitness = fitness.at[gen % P].set(jnp.nan)  # a failed evaluation
        best_row = np.asarray(state.population[jnp.argmin(state.fitness)])
        best_fit = float(np.min(state.fitness))
        state, _ = algo.tell(kt, children, fitness, state_a, params)
        fit_now = np.asarray(state.fitness)
        pop_now = np.asarray(state.population)
        assert state.population.shape == (P, algo.num_dims)
        assert not np.isnan(fit_now).any()
        assert float(state.best_fitness) <= prev_best
        assert fit_now.min() <= prev_min
        # the previous best individual survives with its fitness (or something better replaced it everywhere)
        same = np.all(pop_now == best_row, axis=1)
        assert same.any() or fit_now.max() <= best_fit
        if same.any():
            assert fit_now[same].min() == best_fit
        # the archive's best is the population's best
        assert float(state.best_fitness) == fit_now.min()
        prev_best, prev_min = float(state.best_fitness), fit_now.min()


def test_ga_parents_come_from_the_elites():
    P = 16
    algo, params = _ga(P, elite_ratio=0.25)
    params = params.replace(crossover_rate=0.0, mutation_rate=0.0, branch_mutation_rate=0.0)
    pop = jax.random.uniform(jax.random.key(0), (P, algo.num_dims))
    fitness = jnp.arange(P, dtype=jnp.float32)[::-1]  # the last rows are the best
    state = algo.init(jax.random.key(1), pop, fitness, params)
    children, _ = algo.ask(jax.random.key(2), state, params)
    elites = np.asarray(pop)[P - 4:]  # elite_ratio 0.25 of 16
    for child in np.asarray(children):
        assert np.any(np.all(elites == child, axis=1)), "a child that copies no elite"

