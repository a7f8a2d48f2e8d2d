"""The search as pure functions: start, epochs of generations, finish; and :func:`fit`.

A fit is ``search_init``, then one :func:`search_epoch` per epoch (``epoch``
generations, then the GA's memetic step), then :func:`search_finish` (the final
refinement and the best individual over all islands).  :func:`fit` runs them in one
traced function; :class:`~jaxpose.search.Fitter` runs the same steps as separately
compiled programs, reporting progress between epochs.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax
import jax.numpy as jnp
import optax
from evosax.algorithms.population_based.base import PopulationBasedAlgorithm

from ..errors import ConfigError
from ..genome import decode, genome_layout
from ..kinematics import Links, forward_kinematics
from ..objective import Cloud, cloud_spread, observe
from ..rest_model import RestModel, rest_model
from ..skeleton import Skeleton
from .baselines import BoundedHillClimbing, evosax_strategy
from .coarse import blocks_at, rescore_at_switch
from .config import FitConfig, FitParams
from .cost import population_cost_fn
from .ga import BranchSwapGA, subtree_masks
from .genes import lock, tie_lengths
from .init import initial_population, search_bounds, turned_roots
from .islands import halve_islands, island_map, per_island, vmap_shared
from .memetic import final_refine, keep_better, memetic_apply, refine_top
from .state import SHARED, FitResult, SearchState
from .sweep import limb_sweep, sweep_counts


def make_algorithm(skel: Skeleton, config: FitConfig, params: FitParams):
    """The evosax algorithm of ``config.algorithm`` and its (traced) parameters."""
    D = genome_layout(skel).size
    P = config.population
    decay = (config.std_final / config.std_init) ** (1.0 / max(config.generations, 1))
    schedule = optax.exponential_decay(config.std_init, 1, decay, end_value=config.std_final)
    dummy = jnp.zeros(D, jnp.float32)
    if config.algorithm == "ga":
        algo = BranchSwapGA(P, dummy, subtree_masks(skel), std_schedule=schedule, elite_ratio=config.elite_ratio)
        return algo, algo.default_params.replace(
            crossover_rate=params.crossover_rate,
            mutation_rate=params.mutation_rate,
            branch_mutation_rate=params.branch_mutation_rate,
            branch_reset_rate=params.branch_reset_rate,
        )
    if config.algorithm == "hc":
        algo = BoundedHillClimbing(P, dummy, std_schedule=schedule)
        return algo, algo.default_params
    algo = evosax_strategy(config.algorithm)(P, dummy)
    algo_params = algo.default_params
    if hasattr(algo_params, "std_init"):
        algo_params = algo_params.replace(std_init=config.std_init)
    return algo, algo_params


def start_algorithm(algo, algo_params, key, pop0, fit0):
    """The algorithm's state after evaluating the initial population ``pop0`` (costs
    ``fit0``): a population-based algorithm (the GA, PSO, DE, ...) starts from it; a
    distribution-based one (hill climbing, CMA-ES, ...) at its best individual.
    This counts as the first generation."""
    if isinstance(algo, PopulationBasedAlgorithm):
        state = algo.init(key, pop0, fit0, algo_params)
    else:
        best = jnp.argmin(jnp.where(jnp.isnan(fit0), jnp.inf, fit0))
        state = algo.init(key, pop0[best], algo_params)
        state = state.replace(best_solution=pop0[best], best_fitness=fit0[best])
        if hasattr(state, "best_fitness_shaped"):  # hill climbing moves only to better points
            state = state.replace(best_solution_shaped=pop0[best], best_fitness_shaped=fit0[best])
    return state.replace(generation_counter=1)


def _init_island(skel: Skeleton, config: FitConfig, shared: dict, rest: RestModel, keys: jax.Array) -> SearchState:
    """One island's initial population and a placeholder state of the algorithm: nothing
    is evaluated here (the first generation does it), so this program does not compile
    the cost.  ``keys (3,)``: for the population, the algorithm's init, and the search."""
    obs, bounds, params = (shared[n] for n in SHARED)
    algo, algo_params = make_algorithm(skel, config, params)
    k_pop, k_init, k_run = keys
    pop0 = lock(skel, config, bounds, 0, initial_population(k_pop, skel, obs, bounds, config, params, rest),
                params.staged)
    unknown = jnp.full(pop0.shape[:1], jnp.inf, pop0.dtype)
    state = start_algorithm(algo, algo_params, k_init, pop0, unknown).replace(generation_counter=0)
    zero = jnp.asarray(0, jnp.int32)
    return SearchState(state, k_run, obs, bounds, params, zero, zero, pop0)


def search_init(cloud: Cloud, skel: Skeleton, key: jax.Array, config: FitConfig, params: FitParams) -> SearchState:
    """Initial search state (with a leading island axis when ``config.islands > 1``).
    ``config`` must be resolved (``config.for_skeleton(skel)``: the generations set)."""
    if config.generations is None:
        raise ConfigError("generations is None (automatic): resolve it with config.for_skeleton(skeleton) "
                          "before calling the search's pieces")
    obs = observe(cloud, dataclasses.replace(config.objective, sigma_factor=params.sigma_factor,
                                             free_space_weight=params.free_space_weight,
                                             collision_weight=params.collision_weight))
    rest = rest_model(skel)
    shared = dict(obs=obs, bounds=search_bounds(skel, obs, config, rest, params), params=params)
    if config.islands == 1:
        return _init_island(skel, config, shared, rest, jax.random.split(key, 3))
    # every island's keys in one draw (each draw is a sizeable program to compile)
    return vmap_shared(shared, lambda k: _init_island(skel, config, shared, rest, k),
                       jax.random.split(key, (config.islands, 3)))


def run_generations(skel: Skeleton, config: FitConfig, st: SearchState, length: int):
    """``length`` generations of every island.  The scan runs over generations and
    only the algorithm's ``ask`` and ``tell`` are vmapped over the islands: every
    island's children are scored in one call of the cost on ``(islands * P, D)``
    genomes (a vmapped scan would batch the whole cost kernel, a larger program)."""
    algo, algo_params = make_algorithm(skel, config, st.params)
    pop_cost = population_cost_fn(skel, config, st)
    n_points = st.obs.cloud.points.shape[0]
    unevaluated = st.objective_evaluations == 0  # this program starts the search

    def ask(state, key, initial, first):
        key, k_ask, k_tell = jax.random.split(key, 3)
        pop, asked = algo.ask(k_ask, state, algo_params)
        return jnp.where(first, initial, lock(skel, config, st.bounds, state.generation_counter, pop,
                                               st.params.staged)), asked, key, \
            k_tell

    def tell(k_tell, pop, fitness, asked, first):
        told, _ = algo.tell(k_tell, pop, fitness, asked, algo_params)
        started = start_algorithm(algo, algo_params, k_tell, pop, fitness)
        return jax.tree_util.tree_map(lambda a, b: jnp.where(first, a, b), started, told)

    def generation(carry, i):
        state, key = carry
        first = unevaluated & (i == 0)
        pop, asked, key, k_tell = island_map(config, ask)(state, key, st.initial, first)
        gen = state.generation_counter.reshape(-1)[0]
        fitness = pop_cost(pop.reshape(-1, pop.shape[-1]), blocks_at(config, n_points, gen))
        state = island_map(config, tell)(k_tell, pop, fitness.reshape(pop.shape[:-1]), asked, first)
        return (state, key), jnp.min(state.best_fitness)

    (state, key), hist = jax.lax.scan(generation, (st.algo_state, st.key), jnp.arange(length))
    evals = st.objective_evaluations + length * config.population
    return st._replace(algo_state=state, key=key, objective_evaluations=evals), hist


def search_generations(skel: Skeleton, config: FitConfig, st: SearchState, length: int):
    """:func:`~jaxpose.search.islands.halve_islands` (after the previous epoch's memetic
    step), the coarse-to-fine switch, then ``length`` generations (no refinement).
    Returns the new state and the best cost (over all islands) after each generation."""
    st = rescore_at_switch(skel, config, halve_islands(skel, config, st))
    return run_generations(skel, config, st, length)


class EpochSteps(NamedTuple):
    """The three steps of an epoch: plain functions, or their compiled programs."""

    generations: object = search_generations  # (skel, config, st, length) -> (st, history)
    refine: object = refine_top  # (skel, config, st, m, steps) -> refined
    apply: object = memetic_apply  # (skel, config, st, refined, history) -> (st, history)


def search_epoch(skel: Skeleton, config: FitConfig, st: SearchState, length: int, steps=EpochSteps()):
    """One epoch: ``length`` generations, then the memetic step when it is on.  Returns
    the new state and the best cost (over all islands) after each generation."""
    st, hist = steps.generations(skel, config, st, length)
    if config.memetic_on:
        refined = steps.refine(skel, config, st, config.memetic_rows, jnp.int32(config.memetic_steps))
        st, hist = steps.apply(skel, config, st, refined, hist)
    return st, hist


def evaluation_counts(st: SearchState) -> tuple[jax.Array, jax.Array]:
    """Objective and gradient evaluations so far, summed over islands."""
    return jnp.sum(st.objective_evaluations), jnp.sum(st.gradient_evaluations)


def best_of(st: SearchState) -> tuple[jax.Array, jax.Array]:
    """The best genome ``(D,)`` and its cost over all islands so far (before the final refinement)."""
    g, f = st.algo_state.best_solution, st.algo_state.best_fitness
    if g.ndim == 1:
        return g, f
    i = jnp.argmin(f)
    return g[i], f[i]


def _finish_island(config: FitConfig, st: SearchState, refined):
    """One island's best: ``(genome, cost, evaluations, gradients)``."""
    state = st.algo_state
    best_g, best_f = state.best_solution, state.best_fitness
    evals, grads = st.objective_evaluations, st.gradient_evaluations
    if refined is not None:
        _, g, f = refined
        grads = grads + g.shape[0] * config.final_refine_steps
        best_g, best_f = keep_better(g, f, best_g, best_f)
    return best_g, best_f, evals, grads


def search_result(cloud: Cloud, skel: Skeleton, config: FitConfig, st: SearchState, history, refined) -> FitResult:
    """The :class:`FitResult` of a finished search, given :func:`final_refine`'s output."""
    if config.islands == 1:
        best_g, best_f, evals, grads = _finish_island(config, st, refined)
    else:
        g, f, e, gr = per_island(config, lambda s, r: _finish_island(config, s, r), st, refined)
        i = jnp.argmin(f)
        best_g, best_f, evals, grads = g[i], f[i], jnp.sum(e), jnp.sum(gr)
    best_g = jnp.clip(best_g, 0.0, 1.0)  # evosax strategies sample unbounded; decode clips the same way
    if config.limb_sweep or config.pivot_sweep:
        key = jax.random.fold_in(st.key if config.islands == 1 else st.key[0], 1)
        best_g, best_f = limb_sweep(skel, config, population_cost_fn(skel, config, st), best_g, best_f, key,
                                    st.params.learning_rate, st.bounds)
        e, gr = sweep_counts(skel, config)
        evals, grads = evals + e, grads + gr
    if config.tie_lengths:  # the projection every generation applies, also to the returned best
        best_g = tie_lengths(skel, best_g)
    pose = decode(skel, st.bounds, best_g)
    links = forward_kinematics(skel, pose)
    n_dist = (evals + grads).astype(jnp.float32) * cloud.points.shape[0] * skel.num_links
    return FitResult(pose, best_g, links, best_f, history, evals, grads, n_dist, jnp.asarray(0.0, jnp.float32))


def search_finish(cloud: Cloud, skel: Skeleton, config: FitConfig, st: SearchState, history) -> FitResult:
    """Final refinement, then the best individual over all islands as a :class:`FitResult`."""
    return search_result(cloud, skel, config, st, history, final_refine(skel, config, st))


def cheapest_index(costs: jax.Array) -> jax.Array:
    """The index of the lowest of ``costs`` (NaN counts as the highest)."""
    return jnp.argmin(jnp.where(jnp.isnan(costs), jnp.inf, costs))


def cheapest(results) -> FitResult:
    """The portfolio's answer: of ``results`` (a list of :class:`FitResult`, one per
    search, or one whose leaves have a leading axis of searches) the cheapest (NaN
    costs last), with the evaluation counts of all of them summed."""
    if isinstance(results, list):
        results = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *results)
    i = cheapest_index(results.cost)
    best = jax.tree_util.tree_map(lambda x: x[i], results)
    total = lambda x: jnp.sum(x, axis=0)  # noqa: E731
    return best._replace(objective_evaluations=total(results.objective_evaluations),
                         gradient_evaluations=total(results.gradient_evaluations),
                         distance_evaluations=total(results.distance_evaluations))


def portfolio_keys(key: jax.Array, searches: int) -> list:
    """Each search's key: ``key`` for the first (so a one-search fit is unchanged), then ``fold_in(key, i)``."""
    return [key] + [jax.random.fold_in(key, i) for i in range(1, searches)]


RESTART_SALT = 2**31
"""Restart ``r`` >= 1 runs with ``fold_in(key, RESTART_SALT + r)``: far above the small
indices that :func:`portfolio_keys` and ``split`` inside a search reach."""


def restart_keys(key: jax.Array, restarts: int) -> list:
    """Each restart's key: ``key`` for the first, then ``fold_in(key, RESTART_SALT + r)``,
    so restart ``r`` is the fit without restarts with that key."""
    return [key] + [jax.random.fold_in(key, RESTART_SALT + r) for r in range(1, restarts)]


def round_keys(key: jax.Array, config: FitConfig) -> list[list]:
    """The keys of each restart's searches: :func:`portfolio_keys` of its :func:`restart_keys`
    (:attr:`FitConfig.restarts` lists of :attr:`FitConfig.round_searches`)."""
    return [portfolio_keys(k, config.round_searches) for k in restart_keys(key, config.restarts)]


def answers_apart(skel: Skeleton, a: Links, b: Links) -> jax.Array:
    """How far two answers lie apart, in metres: each link's mean end distance to the
    nearest link of its symmetry orbit in the other answer, averaged over links and both
    ways (so a left/right swap of alike limbs counts as agreement)."""
    orbit = jnp.asarray(skel.orbit)
    d = 0.5 * (jnp.linalg.norm(a.start[:, None] - b.start[None], axis=-1)
               + jnp.linalg.norm(a.end[:, None] - b.end[None], axis=-1))
    d = jnp.where(orbit[:, None] == orbit[None, :], d, jnp.inf)
    return 0.5 * (jnp.mean(jnp.min(d, axis=1)) + jnp.mean(jnp.min(d, axis=0)))


def answers_disagree(skel: Skeleton, config: FitConfig, costs: jax.Array, links: Links,
                     spread: jax.Array) -> jax.Array:
    """Whether another restart is wanted (:attr:`FitConfig.restart_apart`): the cheapest
    of the answers so far (``costs (S,)``, ``links`` with a leading ``S`` axis) and the next
    cheapest lie more than ``restart_apart * spread`` (the cloud's spread) apart."""
    i = cheapest_index(costs)
    j = cheapest_index(costs.at[i].set(jnp.nan))
    pick = lambda k: jax.tree_util.tree_map(lambda x: x[k], links)  # noqa: E731
    return answers_apart(skel, pick(i), pick(j)) > config.restart_apart * spread


_disagree_jit = jax.jit(answers_disagree, static_argnums=1)


def run_searches(skel: Skeleton, config: FitConfig, params: FitParams, key: jax.Array, search,
                 cloud: Cloud | None = None) -> list:
    """Every search of a fit, one after another: per restart, the portfolio's, then
    the turn searches about that portfolio's cheapest answer.  ``search(key, params)``
    runs one and returns its :class:`FitResult`; returns them all, in order.  With
    :attr:`FitConfig.restart_apart` a restart runs only when the answers so far disagree
    about ``cloud`` (required then).  The Python driver of :meth:`Fitter.run` and
    :func:`~jaxpose.parallel.fit_islands`; :func:`fit` traces the same order."""
    if config.restart_apart and config.restarts > 1 and cloud is None:
        raise ConfigError("run_searches: adaptive restarts (restart_apart > 0) need the cloud")
    out = []
    for r, keys in enumerate(round_keys(key, config)):
        if r and config.restart_apart:
            stacked = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *[res.links for res in out])
            costs = jnp.stack([res.cost for res in out])
            f32 = lambda x: jnp.asarray(x, jnp.float32)  # noqa: E731  (as the searches see the cloud)
            spread = cloud_spread(Cloud(f32(cloud.points), f32(cloud.weights)))
            if not bool(_disagree_jit(skel, config, costs, stacked, spread)):
                break
        done = [search(k, p) for k, p in zip(keys, config.search_params(params))]
        if config.turns:
            answer = done[int(cheapest_index(jnp.stack([r.cost for r in done])))]
            done += [search(k, p) for k, p in
                     zip(keys[config.portfolio:], turn_params(skel, config, params, answer.pose.root_rpy))]
        out += done
    return out


def turn_params(skel: Skeleton, config: FitConfig, params: FitParams, root_rpy: jax.Array) -> list[FitParams]:
    """The traced settings of the turn searches (:attr:`FitConfig.turns`) about an
    answer whose root orientation is ``root_rpy``: unstaged, the root held within
    ``turn_window`` of each of :func:`~jaxpose.search.init.turned_roots`."""
    window = jnp.asarray(config.turn_window, jnp.float32)
    return [params.replace(staged=jnp.asarray(0.0, jnp.float32), root_rpy=r.astype(jnp.float32), root_window=window)
            for r in turned_roots(skel, root_rpy, config.turns)]


def single_search(cloud: Cloud, skeleton: Skeleton, key: jax.Array, config: FitConfig, params: FitParams) -> FitResult:
    """One search of a resolved, static ``config`` with the traced ``params``: start, epochs, finish."""
    st = search_init(cloud, skeleton, key, config, params)
    lengths = config.epoch_lengths
    E, n_full = config.epoch, config.generations // config.epoch
    hists = []
    if n_full:
        st, h = jax.lax.scan(lambda s, _: search_epoch(skeleton, config, s, E), st, None, length=n_full)
        hists.append(h.reshape(-1))
    if len(lengths) > n_full:
        st, h = search_epoch(skeleton, config, st, lengths[-1])
        hists.append(h)
    return search_finish(cloud, skeleton, config, st, jnp.concatenate(hists))


def fit(cloud: Cloud, skeleton: Skeleton, key: jax.Array, config: FitConfig = FitConfig(),
        params: FitParams | None = None) -> FitResult:
    """Search ``skeleton``'s parameters that best explain ``cloud`` (camera frame).

    Pure and jit-compatible (``config`` is static); vmappable over clouds and keys::

        fit_jit = jax.jit(fit, static_argnames="config")
        batch = jax.vmap(fit_jit, in_axes=(0, None, 0, None))(clouds, skel, keys, config)

    ``params`` (default ``config.params()``) are the traced settings: pass them to
    sweep rates or weights under one compiled program (even vmapped over them).
    With ``config.staged_alternatives`` the searches of the portfolio run one after
    another (``lax.map``: one traced search), then ``config.turns`` turn searches
    about the cheapest answer, and the cheapest answer of all is returned; with
    ``config.restarts`` that whole round runs again (``lax.map``) with keys of its
    own (:func:`round_keys`), and the cheapest round's answer is returned; with
    ``config.restart_apart`` each later round runs under ``lax.cond`` only when the
    answers so far disagree (:func:`answers_disagree`), as :func:`run_searches` decides.
    """
    config = config.validate().for_skeleton(skeleton)
    params = config.params() if params is None else params
    every, n = config.search_params(params), config.portfolio
    static = config.static()
    stack = lambda trees: jax.tree_util.tree_map(lambda *x: jnp.stack(x), *trees)  # noqa: E731
    searches = lambda ks, ps: jax.lax.map(  # noqa: E731  (ks: a list of keys, or stacked inside the restarts' map)
        lambda kp: single_search(cloud, skeleton, kp[0], static, kp[1]),
        (ks if isinstance(ks, jax.Array) else jnp.stack(ks), stack(ps)))

    def one_round(keys):  # the portfolio, then the turns about its answer, as Fitter.run
        res = single_search(cloud, skeleton, keys[0], static, params) if n == 1 else cheapest(searches(keys[:n], every))
        if config.turns:
            turned = searches(keys[n:], turn_params(skeleton, config, params, res.pose.root_rpy))
            res = cheapest(jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a[None], b]), res, turned))
        return res

    rounds = round_keys(key, config)
    if config.restarts == 1:  # the keys as a list: the program of a fit without restarts, as before them
        return one_round(rounds[0])
    if not config.restart_apart:
        return cheapest(jax.lax.map(one_round, jnp.stack([jnp.stack(ks) for ks in rounds])))

    def round_answers(keys):  # every answer of a round, stacked, in run_searches' order
        ans = searches(keys[:n], every) if n > 1 else \
            jax.tree_util.tree_map(lambda x: x[None], single_search(cloud, skeleton, keys[0], static, params))
        if config.turns:
            rpy = ans.pose.root_rpy[cheapest_index(ans.cost)]
            turned = searches(keys[n:], turn_params(skeleton, config, params, rpy))
            ans = jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a, b]), ans, turned)
        return ans

    spread = cloud_spread(cloud)
    answers = round_answers(jnp.stack(rounds[0]))
    skipped = jax.tree_util.tree_map(jnp.zeros_like, answers)  # a round not run: no answer, nothing counted
    skipped = skipped._replace(cost=jnp.full_like(answers.cost, jnp.inf))
    for ks in rounds[1:]:  # a restart only when the answers so far disagree (lax.cond: skipped unless vmapped)
        more = jax.lax.cond(answers_disagree(skeleton, config, answers.cost, answers.links, spread),
                            round_answers, lambda _: skipped, jnp.stack(ks))
        answers = jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a, b]), answers, more)
    return cheapest(answers)
