"""``fit``: search a skeleton's parameters for the pose that best explains a cloud.

The whole search is pure JAX: :func:`fit` is jit-compatible and vmappable over a
batch of clouds.  :class:`Fitter` runs the same steps one compiled chunk at a time
so that a caller (the command line) can show progress between chunks.

Budget.  ``population`` individuals are evaluated in the initial population and
in each of ``generations`` generations.  Refinement adds gradient evaluations (a
cost and its gradient) and a few plain evaluations.  ``FitResult`` reports exact
counts; ``distance_evaluations`` counts point-to-capsule distances
(``(objective + gradient evaluations) * N * L`` with ``N`` the cloud's array size).
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass, field
from functools import partial
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
from evosax.algorithms.population_based.base import PopulationBasedAlgorithm

from ..errors import ConfigError
from ..kinematics import Links, forward_kinematics
from ..objective import Cloud, ObjectiveConfig, Observation, cloud_centre, cloud_spread, observe, population_cost
from ..skeleton import Bounds, Pose, Skeleton, decode, encode, genome_bounds, genome_layout, rest_pose
from .baselines import BoundedHillClimbing, evosax_strategy
from .ga import BranchSwapGA, subtree_masks
from .refine import refine


@dataclass(frozen=True)
class FitConfig:
    """Search settings (hashable: a static argument of the compiled fit).

    Attributes:
        algorithm: ``"ga"`` (branch-swap GA), ``"hc"`` (hill climbing) or the name
            of any evosax strategy (e.g. ``"cma_es"``).
        population: individuals evaluated per generation.
        generations: number of generations.
        chunk: generations per compiled chunk (progress granularity) when
            ``memetic_every`` is 0.
        std_init, std_final: mutation / sampling step in normalised genome units,
            decayed exponentially over the generations.
        crossover_rate: probability that a child takes a subtree from a second parent.
        mutation_rate: per-gene mutation probability.
        branch_mutation_rate: probability that a child mutates one whole subtree instead.
        branch_reset_rate: probability that a child then draws every gene of one random
            subtree anew (uniform within its bounds): a jump that gets a limb out of a
            local optimum at any step size (7 humanoid tuning images: symmetric PCP
            0.53 -> 0.70, final cost 0.096 -> 0.071, the truth's 0.060).
        elite_ratio: fraction of the population that may become parents.
        memetic_every: every this many generations, refine the ``memetic_top`` best
            individuals by ``memetic_steps`` Adam steps (0: never).
        final_refine_steps: Adam steps at the end (0: none) on the ``final_refine_top`` best
            individuals (the GA) or on the best point (other algorithms).
        learning_rate: Adam learning rate (genome units).
        init_root_std: spread of the initial root translation genes around the
            cloud's centre (genome units).
        init_pca_fraction: fraction of the initial population whose root
            orientation aligns the model's principal axes (rest pose) with the
            cloud's, one of the four proper sign choices at random, and whose root
            puts the model's centre behind the cloud's centre (0: all uniform).
        init_pca_std: noise on those individuals' root genes (genome units).
        scale_window: the global scale is searched within ``s0 / w .. s0 * w``
            (intersected with the skeleton's range), ``s0`` being the cloud's
            spread over the rest-pose model's (0: the skeleton's range alone).
        staged: trunk before limbs: during the first ``staged`` fraction of the
            generations the links are unlocked level by level down the tree
            (links at depth ``d`` join after ``d / levels`` of that phase);
            locked links hold their rest pose (0: everything searched at once).
        islands: independent sub-populations of ``population`` individuals each,
            searched side by side (vmapped); the fit returns the best island's
            refined best.  The budget grows with the number of islands.
        objective: the cost's settings.
    """

    algorithm: str = "ga"
    population: int = 256
    generations: int = 300
    chunk: int = 25
    std_init: float = 0.15
    std_final: float = 0.01
    crossover_rate: float = 0.5
    mutation_rate: float = 0.15
    branch_mutation_rate: float = 0.3
    branch_reset_rate: float = 0.1
    elite_ratio: float = 0.25
    memetic_every: int = 25
    memetic_top: int = 8
    memetic_steps: int = 10
    final_refine_top: int = 4
    final_refine_steps: int = 100
    learning_rate: float = 0.01
    init_root_std: float = 0.1
    init_pca_fraction: float = 0.5
    init_pca_std: float = 0.02
    scale_window: float = 1.5
    islands: int = 8
    staged: float = 0.5
    objective: ObjectiveConfig = field(default_factory=ObjectiveConfig)

    def validate(self) -> "FitConfig":
        if not isinstance(self.population, int) or self.population < 2:
            raise ConfigError(f"population must be an integer >= 2, got {self.population!r}")
        if not isinstance(self.generations, int) or self.generations < 1:
            raise ConfigError(f"generations must be an integer >= 1, got {self.generations!r}")
        if not isinstance(self.islands, int) or self.islands < 1:
            raise ConfigError(f"islands must be an integer >= 1, got {self.islands!r}")
        if self.chunk < 1:
            raise ConfigError(f"chunk must be >= 1, got {self.chunk}")
        if self.algorithm not in ("ga", "hc"):
            evosax_strategy(self.algorithm)
        for name in ("crossover_rate", "mutation_rate", "branch_mutation_rate", "branch_reset_rate"):
            v = getattr(self, name)
            if not 0.0 <= v <= 1.0:
                raise ConfigError(f"{name} must lie in [0, 1], got {v}")
        if self.scale_window != 0 and self.scale_window <= 1.0:
            raise ConfigError(f"scale_window must be > 1 (or 0 for the skeleton's range), got {self.scale_window}")
        if not 0.0 <= self.staged <= 1.0:
            raise ConfigError(f"staged must lie in [0, 1], got {self.staged}")
        if not 0.0 <= self.init_pca_fraction <= 1.0:
            raise ConfigError(f"init_pca_fraction must lie in [0, 1], got {self.init_pca_fraction}")
        if not 0.0 < self.elite_ratio <= 1.0:
            raise ConfigError(f"elite_ratio must lie in (0, 1], got {self.elite_ratio}")
        if self.std_init <= 0 or self.std_final <= 0:
            raise ConfigError("std_init and std_final must be positive")
        for name in ("memetic_every", "memetic_top", "memetic_steps", "final_refine_top", "final_refine_steps"):
            if getattr(self, name) < 0:
                raise ConfigError(f"{name} must be >= 0, got {getattr(self, name)}")
        return self

    @property
    def epoch(self) -> int:
        """Generations per compiled chunk."""
        return self.memetic_every if self.memetic_on else self.chunk

    @property
    def memetic_on(self) -> bool:
        return self.algorithm == "ga" and self.memetic_every > 0 and self.memetic_top > 0 and self.memetic_steps > 0

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


class FitResult(NamedTuple):
    """What a fit returns (a pytree; every leaf gains a batch axis under vmap)."""

    pose: Pose  # best parameters, physical units
    genome: jax.Array  # (D,) best genome
    links: Links  # posed links of the best parameters (camera frame)
    cost: jax.Array  # () final cost
    history: jax.Array  # (generations,) best cost after each generation
    objective_evaluations: jax.Array  # () int
    gradient_evaluations: jax.Array  # () int
    distance_evaluations: jax.Array  # () float (can exceed int32)
    wall_time: jax.Array  # () seconds, filled in by Fitter / fit_cloud (0 inside jit)


class SearchState(NamedTuple):
    algo_state: Any
    key: jax.Array
    obs: Observation
    bounds: Bounds
    objective_evaluations: jax.Array
    gradient_evaluations: jax.Array


# --------------------------------------------------------------------------- pieces


def _make_algorithm(skel: Skeleton, config: FitConfig):
    D = genome_layout(skel).size
    P = config.population
    decay = (config.std_final / config.std_init) ** (1.0 / max(config.generations, 1))
    schedule = optax.exponential_decay(config.std_init, 1, decay, end_value=config.std_final)
    dummy = jnp.zeros(D, jnp.float32)
    if config.algorithm == "ga":
        algo = BranchSwapGA(P, dummy, subtree_masks(skel), std_schedule=schedule, elite_ratio=config.elite_ratio)
        params = algo.default_params.replace(
            crossover_rate=config.crossover_rate,
            mutation_rate=config.mutation_rate,
            branch_mutation_rate=config.branch_mutation_rate,
            branch_reset_rate=config.branch_reset_rate,
        )
        return algo, params
    if config.algorithm == "hc":
        algo = BoundedHillClimbing(P, dummy, std_schedule=schedule)
        return algo, algo.default_params
    cls = evosax_strategy(config.algorithm)
    algo = cls(P, dummy)
    params = algo.default_params
    if hasattr(params, "std_init"):
        params = params.replace(std_init=config.std_init)
    return algo, params


def _population_cost_fn(skel: Skeleton, obs: Observation, bounds: Bounds, config: FitConfig):
    def cost(genomes):
        poses = jax.vmap(partial(decode, skel, bounds))(genomes)
        links = jax.vmap(partial(forward_kinematics, skel))(poses)
        c = population_cost(obs, links.start, links.end, links.radius, config.objective)
        return jnp.where(jnp.isfinite(c), c, jnp.inf)

    return cost


def _single_cost_fn(skel, obs, bounds, config):
    pop_cost = _population_cost_fn(skel, obs, bounds, config)
    return lambda g: pop_cost(g[None])[0]


def _model_samples(skel: Skeleton) -> jax.Array:
    """Points along the rest-pose capsule axes at scale 1 (skeleton frame)."""
    links = forward_kinematics(skel, rest_pose(skel))
    t = jnp.linspace(0.0, 1.0, 8)[:, None, None]
    return (links.start[None] + t * (links.end - links.start)[None]).reshape(-1, 3)


class RestModel(NamedTuple):
    """The rest-pose model's shape at scale 1: centroid, principal axes, RMS spread."""

    centre: jax.Array  # (3,)
    axes: jax.Array  # (3, 3) columns by decreasing variance
    spread: jax.Array  # ()


def rest_model(skel: Skeleton) -> RestModel:
    """:class:`RestModel` of ``skel`` (one forward-kinematics pass of the rest pose)."""
    pts = _model_samples(skel)
    c, axes = principal_axes(pts, jnp.ones(pts.shape[0]))
    return RestModel(c, axes, jnp.sqrt(jnp.mean(jnp.sum((pts - c) ** 2, -1)) + 1e-12))


def principal_axes(points: jax.Array, weights: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Weighted centroid and principal axes (columns, by decreasing variance) of points."""
    wsum = jnp.maximum(jnp.sum(weights), 1e-12)
    c = jnp.sum(points * weights[:, None], 0) / wsum
    d = points - c
    cov = (d * weights[:, None]).T @ d / wsum + 1e-9 * jnp.eye(3)
    _, vec = jnp.linalg.eigh(cov)  # ascending eigenvalues
    return c, vec[:, ::-1]


def matrix_rpy(R: jax.Array) -> jax.Array:
    """(roll, pitch, yaw) of ``R = Rz(yaw) Ry(pitch) Rx(roll)``; the inverse of ``rpy_matrix``."""
    pitch = jnp.arcsin(jnp.clip(-R[2, 0], -1.0, 1.0))
    return jnp.stack([jnp.arctan2(R[2, 1], R[2, 2]), pitch, jnp.arctan2(R[1, 0], R[0, 0])])


def aligned_root(key, skel: Skeleton, obs: Observation, scale, rest: RestModel | None = None):
    """A root pose ``(translation, rpy)`` that aligns the rest-pose model's principal
    axes with the cloud's.

    The sign of each axis is ambiguous: one of the four proper rotations is picked
    with ``key``.  The model's centroid lands half a mean link radius behind the
    cloud's centroid (the cloud only covers the surface facing the camera).
    ``rest`` (:func:`rest_model`) may be passed to skip recomputing it.
    """
    m_c, M = (rest or rest_model(skel))[:2]
    c_c, C = principal_axes(obs.cloud.points, obs.cloud.weights)
    s12 = jnp.where(jax.random.bernoulli(key, 0.5, (2,)), 1.0, -1.0)
    s3 = s12[0] * s12[1] * jnp.sign(jnp.linalg.det(C) * jnp.linalg.det(M))
    R = (C * jnp.concatenate([s12, s3[None]])[None]) @ M.T
    ray = c_c / jnp.maximum(jnp.linalg.norm(c_c), 1e-9)
    centre = c_c + ray * 0.5 * scale * jnp.mean(skel.radius)
    return centre - scale * R @ m_c, matrix_rpy(R)


def initial_scale(skel: Skeleton, obs: Observation, config: FitConfig, rest: RestModel | None = None) -> jax.Array:
    """The scale at which the rest-pose model spreads like the cloud."""
    s0 = cloud_spread(obs.cloud) / (rest or rest_model(skel)).spread
    return jnp.clip(s0, skel.scale_lo, skel.scale_hi)


def search_bounds(skel: Skeleton, obs: Observation, config: FitConfig, rest: RestModel | None = None) -> Bounds:
    """Gene ranges for this cloud: root within the cloud's extent, scale near :func:`initial_scale`."""
    centre = cloud_centre(obs.cloud)
    d = jnp.sqrt(jnp.sum((obs.cloud.points - centre) ** 2, -1))
    extent = jnp.maximum(jnp.max(jnp.where(obs.cloud.weights > 0, d, 0.0)), 1e-3)
    bounds = genome_bounds(skel, centre, extent)
    if config.scale_window:
        s0 = initial_scale(skel, obs, config, rest)
        i = genome_layout(skel).names.index("scale")
        lo = jnp.maximum(skel.scale_lo, s0 / config.scale_window)
        hi = jnp.maximum(jnp.minimum(skel.scale_hi, s0 * config.scale_window), lo)
        bounds = Bounds(bounds.lo.at[i].set(lo), bounds.hi.at[i].set(hi))
    return bounds


def initial_population(key, skel: Skeleton, obs: Observation, bounds: Bounds, config: FitConfig,
                       rest: RestModel | None = None) -> jax.Array:
    """Data-driven initial genomes: root near the cloud's centre, scale from the
    cloud's spread against the model's, orientation and joint angles uniform within
    limits, lengths near their rest values.  A fraction ``init_pca_fraction`` gets a
    root aligned with the cloud's principal axes instead (:func:`aligned_root`)."""
    rest = rest or rest_model(skel)
    layout = genome_layout(skel)
    P, D = config.population, layout.size
    k_u, k_t, k_s, k_l, k_a, k_n = jax.random.split(key, 6)
    g = jax.random.uniform(k_u, (P, D))
    names = layout.names
    root_t = np.array([n in ("root_tx", "root_ty", "root_tz") for n in names])
    scale_i = names.index("scale")
    is_len = np.array([n.endswith(".length") for n in names])
    g = jnp.where(root_t, 0.5 + config.init_root_std * jax.random.normal(k_t, (P, D)), g)
    s0 = initial_scale(skel, obs, config, rest)
    s_lo, s_hi = bounds.lo[scale_i], bounds.hi[scale_i]
    s_gene = (s0 * jnp.exp(0.15 * jax.random.normal(k_s, (P,))) - s_lo) / jnp.maximum(s_hi - s_lo, 1e-9)
    g = g.at[:, scale_i].set(s_gene)
    rest_g = encode(skel, bounds, rest_pose(skel))
    g = jnp.where(is_len, rest_g + 0.1 * jax.random.normal(k_l, (P, D)), g)
    n_pca = int(round(config.init_pca_fraction * P))
    if n_pca > 0:
        t, rpy = jax.vmap(lambda k: aligned_root(k, skel, obs, s0, rest))(jax.random.split(k_a, n_pca))
        span = jnp.maximum(bounds.hi[:6] - bounds.lo[:6], 1e-9)
        root_g = (jnp.concatenate([t, rpy], 1) - bounds.lo[:6]) / span
        root_g = root_g + config.init_pca_std * jax.random.normal(k_n, root_g.shape)
        g = g.at[:n_pca, :6].set(root_g)
    return jnp.clip(g, 0.0, 1.0)


def _gene_levels(skel: Skeleton) -> np.ndarray:
    """Tree depth of every gene's link (-1 for the root genes)."""
    depth = np.zeros(skel.num_links, np.int32)
    for d, level in enumerate(skel.levels):
        depth[list(level)] = d
    link = np.asarray(genome_layout(skel).link_of_gene)
    return np.where(link >= 0, depth[np.maximum(link, 0)], -1)


def _unlocked(skel: Skeleton, config: FitConfig, generation) -> jax.Array:
    """Boolean ``(D,)``: the genes searched at ``generation`` (see ``FitConfig.staged``)."""
    levels = _gene_levels(skel)
    if config.staged <= 0:
        return jnp.ones(levels.shape, bool)
    phase = config.staged * config.generations / len(skel.levels)
    return jnp.asarray(levels) <= jnp.floor(generation / phase)


def _lock(skel: Skeleton, config: FitConfig, bounds: Bounds, generation, genomes):
    """Locked genes (staged search) set to their rest values."""
    if config.staged <= 0:
        return genomes
    rest = encode(skel, bounds, rest_pose(skel))
    return jnp.where(_unlocked(skel, config, generation), genomes, rest)


def _search_init1(cloud: Cloud, skel: Skeleton, key: jax.Array, config: FitConfig) -> SearchState:
    obs = observe(cloud, config.objective)
    rest = rest_model(skel)
    bounds = search_bounds(skel, obs, config, rest)
    algo, params = _make_algorithm(skel, config)
    k_pop, k_init, k_run = jax.random.split(key, 3)
    pop0 = _lock(skel, config, bounds, 0, initial_population(k_pop, skel, obs, bounds, config, rest))
    fit0 = _population_cost_fn(skel, obs, bounds, config)(pop0)
    if isinstance(algo, PopulationBasedAlgorithm):  # the GA, PSO, DE, evosax's SimpleGA, ...
        state = algo.init(k_init, pop0, fit0, params)
    else:  # distribution-based (hill climbing, CMA-ES, ...): start at the best initial individual
        best = jnp.argmin(fit0)
        state = algo.init(k_init, pop0[best], params)
        state = state.replace(best_solution=pop0[best], best_fitness=fit0[best])
        if hasattr(state, "best_fitness_shaped"):  # hill climbing moves only to better points
            state = state.replace(best_solution_shaped=pop0[best], best_fitness_shaped=fit0[best])
    P = config.population
    return SearchState(state, k_run, obs, bounds, jnp.asarray(P, jnp.int32), jnp.asarray(0, jnp.int32))


def _memetic(skel, config, st: SearchState, algo_state, cost1):
    m = min(config.memetic_top, config.population)
    order = jnp.argsort(algo_state.fitness)[:m]
    g, f = refine(cost1, algo_state.population[order], config.memetic_steps, config.learning_rate)
    pop = algo_state.population.at[order].set(g)
    fit = algo_state.fitness.at[order].set(f)
    i = jnp.argmin(f)
    better = f[i] < algo_state.best_fitness
    return algo_state.replace(
        population=pop,
        fitness=fit,
        best_solution=jnp.where(better, g[i], algo_state.best_solution),
        best_fitness=jnp.where(better, f[i], algo_state.best_fitness),
    )


def _search_epoch1(skel: Skeleton, config: FitConfig, st: SearchState, length: int):
    algo, params = _make_algorithm(skel, config)
    pop_cost = _population_cost_fn(skel, st.obs, st.bounds, config)

    def generation(carry, _):
        state, key = carry
        key, k_ask, k_tell = jax.random.split(key, 3)
        pop, state = algo.ask(k_ask, state, params)
        pop = _lock(skel, config, st.bounds, state.generation_counter, pop)
        fitness = pop_cost(pop)
        state, _ = algo.tell(k_tell, pop, fitness, state, params)
        return (state, key), state.best_fitness

    (state, key), hist = jax.lax.scan(generation, (st.algo_state, st.key), None, length=length)
    evals = st.objective_evaluations + length * config.population
    grads = st.gradient_evaluations
    if config.memetic_on:
        cost1 = _single_cost_fn(skel, st.obs, st.bounds, config)
        gen = state.generation_counter
        state = _memetic(skel, config, st, state, lambda g: cost1(_lock(skel, config, st.bounds, gen, g)))
        state = state.replace(population=_lock(skel, config, st.bounds, gen, state.population),
                              best_solution=_lock(skel, config, st.bounds, gen, state.best_solution))
        m = min(config.memetic_top, config.population)
        evals = evals + m
        grads = grads + m * config.memetic_steps
        hist = hist.at[-1].set(state.best_fitness)
    return st._replace(algo_state=state, key=key, objective_evaluations=evals, gradient_evaluations=grads), hist


def search_init(cloud: Cloud, skel: Skeleton, key: jax.Array, config: FitConfig) -> SearchState:
    """Initial search state (with a leading island axis when ``config.islands > 1``)."""
    if config.islands == 1:
        return _search_init1(cloud, skel, key, config)
    keys = jax.random.split(key, config.islands)
    return jax.vmap(lambda k: _search_init1(cloud, skel, k, config))(keys)


def search_epoch(skel: Skeleton, config: FitConfig, st: SearchState, length: int):
    """Run ``length`` generations (then a memetic refinement, when on).  Returns the
    new state and the best cost (over all islands) after each generation ``(length,)``."""
    if config.islands == 1:
        return _search_epoch1(skel, config, st, length)
    st, hist = jax.vmap(lambda s: _search_epoch1(skel, config, s, length))(st)
    return st, jnp.min(hist, 0)


def evaluation_counts(st: SearchState) -> tuple[jax.Array, jax.Array]:
    """Objective and gradient evaluations so far, summed over islands."""
    return jnp.sum(st.objective_evaluations), jnp.sum(st.gradient_evaluations)


def _finish1(skel: Skeleton, config: FitConfig, st: SearchState):
    """Refine one island's best candidates; returns ``(genome, cost, evaluations, gradients)``."""
    state = st.algo_state
    cost1 = _single_cost_fn(skel, st.obs, st.bounds, config)
    best_g, best_f = state.best_solution, state.best_fitness
    evals, grads = st.objective_evaluations, st.gradient_evaluations
    if config.final_refine_steps > 0 and config.final_refine_top > 0:
        if config.algorithm == "ga":  # elitism keeps the best in the population
            m = min(config.final_refine_top, config.population)
            cand = state.population[jnp.argsort(state.fitness)[:m]]
        else:
            cand = best_g[None]
        g, f = refine(cost1, cand, config.final_refine_steps, config.learning_rate)
        evals = evals + cand.shape[0]
        grads = grads + cand.shape[0] * config.final_refine_steps
        i = jnp.argmin(f)
        better = f[i] < best_f
        best_g = jnp.where(better, g[i], best_g)
        best_f = jnp.where(better, f[i], best_f)
    return best_g, best_f, evals, grads


def search_finish(cloud: Cloud, skel: Skeleton, config: FitConfig, st: SearchState, history) -> FitResult:
    if config.islands == 1:
        best_g, best_f, evals, grads = _finish1(skel, config, st)
        bounds = st.bounds
    else:
        g, f, e, gr = jax.vmap(lambda s: _finish1(skel, config, s))(st)
        i = jnp.argmin(f)
        best_g, best_f, evals, grads = g[i], f[i], jnp.sum(e), jnp.sum(gr)
        bounds = jax.tree_util.tree_map(lambda x: x[0], st.bounds)
    best_g = jnp.clip(best_g, 0.0, 1.0)  # evosax strategies sample unbounded; decode clips the same way
    pose = decode(skel, bounds, best_g)
    links = forward_kinematics(skel, pose)
    n_dist = (evals + grads).astype(jnp.float32) * cloud.points.shape[0] * skel.num_links
    return FitResult(pose, best_g, links, best_f, history, evals, grads, n_dist, jnp.asarray(0.0, jnp.float32))


def _epochs(config: FitConfig) -> tuple[int, int, int]:
    E = config.epoch
    return E, config.generations // E, config.generations % E


def fit(cloud: Cloud, skeleton: Skeleton, key: jax.Array, config: FitConfig = FitConfig()) -> FitResult:
    """Search ``skeleton``'s parameters that best explain ``cloud`` (camera frame).

    Pure and jit-compatible (``config`` is static); vmappable over clouds and keys::

        fit_jit = jax.jit(fit, static_argnames="config")
        batch = jax.vmap(fit_jit, in_axes=(0, None, 0, None))(clouds, skel, keys, config)
    """
    config.validate()
    st = search_init(cloud, skeleton, key, config)
    E, n_full, rem = _epochs(config)
    hists = []
    if n_full:
        st, h = jax.lax.scan(lambda s, _: search_epoch(skeleton, config, s, E), st, None, length=n_full)
        hists.append(h.reshape(-1))
    if rem:
        st, h = search_epoch(skeleton, config, st, rem)
        hists.append(h)
    return search_finish(cloud, skeleton, config, st, jnp.concatenate(hists))


_init_jit = jax.jit(search_init, static_argnames="config")
_epoch_jit = jax.jit(search_epoch, static_argnames=("config", "length"))
_finish_jit = jax.jit(search_finish, static_argnames="config")


class Fitter:
    """Run :func:`fit`'s steps one compiled chunk at a time, for progress reports.

    ``progress(generation, best_cost, evaluations)`` is called after every chunk.
    """

    def __init__(self, skeleton: Skeleton, config: FitConfig = FitConfig()):
        self.skeleton = skeleton
        self.config = config.validate()

    def run(self, cloud: Cloud, key: jax.Array, progress=None) -> FitResult:
        cloud = Cloud(jnp.asarray(cloud.points, jnp.float32), jnp.asarray(cloud.weights, jnp.float32))
        t0 = time.perf_counter()
        st = _init_jit(cloud, self.skeleton, key, self.config)
        E, n_full, rem = _epochs(self.config)
        hists, gen = [], 0
        for length in [E] * n_full + ([rem] if rem else []):
            st, h = _epoch_jit(self.skeleton, self.config, st, length)
            hists.append(h)
            gen += length
            if progress is not None:
                progress(gen, float(h[-1]), int(sum(evaluation_counts(st))))
        res = _finish_jit(cloud, self.skeleton, self.config, st, jnp.concatenate(hists))
        res = jax.block_until_ready(res)
        return res._replace(wall_time=jnp.asarray(time.perf_counter() - t0, jnp.float32))


def fit_cloud(cloud: Cloud, skeleton: Skeleton, seed: int = 0, config: FitConfig = FitConfig(), progress=None) -> FitResult:
    """Convenience: :class:`Fitter` with an integer seed; returns NumPy-friendly results."""
    return Fitter(skeleton, config).run(cloud, jax.random.key(seed), progress)
