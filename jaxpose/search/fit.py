"""``fit``: search a skeleton's parameters for the pose that best explains a cloud.

The whole search is pure JAX: :func:`fit` is jit-compatible and vmappable over a
batch of clouds.  :class:`Fitter` runs the same steps one compiled chunk at a time
so that a caller (the command line) can show progress between chunks.

Budget.  ``population`` individuals are evaluated in each of ``generations``
generations, the first of which is the initial population.  Refinement adds
gradient evaluations (a cost and its gradient), ``memetic_steps`` or
``final_refine_steps`` per refined individual.  ``FitResult`` reports exact
counts; ``distance_evaluations`` counts point-to-capsule distances
(``(objective + gradient evaluations) * N * L`` with ``N`` the cloud's array size).
"""

from __future__ import annotations

import dataclasses
import time
from collections import OrderedDict
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from functools import partial
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
from evosax.algorithms.population_based.base import PopulationBasedAlgorithm

from .._xla_flags import fast_compile_options
from ..errors import ConfigError
from ..kinematics import Links, collision_pairs, forward_kinematics
from ..objective import (Cloud, ObjectiveConfig, Observation, cloud_centre, cloud_spread, num_blocks, observe,
                         population_cost)
from ..skeleton import (Bounds, Pose, Skeleton, axis_angle_matrix, decode, encode, genome_bounds, genome_layout,
                        rest_pose)
from .baselines import BoundedHillClimbing, evosax_strategy
from .ga import BranchSwapGA, subtree_masks, uniform_and_normal
from .refine import refine


GENERATIONS_PER_GENE = 4
GENERATIONS_RANGE = (100, 300)


def auto_generations(skel: Skeleton, epoch: int = 25) -> int:
    """The default number of generations for ``skel``: ``GENERATIONS_PER_GENE`` per
    searched gene, clipped to ``GENERATIONS_RANGE``, rounded to whole epochs of
    ``epoch`` generations (a shorter last epoch would be one more program to compile:
    the spider's cold fit takes 12 s at 156 generations, 9-10 s at 150)."""
    lo, hi = GENERATIONS_RANGE
    g = min(hi, max(lo, GENERATIONS_PER_GENE * genome_layout(skel).size))
    return int(epoch * max(1, round(g / epoch)))


@dataclass(frozen=True)
class FitConfig:
    """Search settings (hashable: a static argument of the compiled fit).

    Attributes:
        algorithm: ``"ga"`` (branch-swap GA), ``"hc"`` (hill climbing) or the name
            of any evosax strategy (e.g. ``"cma_es"``).
        population: individuals evaluated per generation (per island).
        generations: number of generations; the first evaluates the initial
            population.  ``None`` (the default): chosen for the skeleton by
            :meth:`for_skeleton`, ``GENERATIONS_PER_GENE`` (4) per searched gene
            within ``GENERATIONS_RANGE`` (100 .. 300), rounded to whole epochs
            (:func:`auto_generations`): the spider's 39 genes get 150, the
            humanoid's 75 get 300, a 7-joint arm's 21 get 100.  A small
            skeleton needs fewer generations (spider tuning images, 2 seeds: 100%
            link accuracy at 300, 99.4% at 150 and 99.4-100% at 100, in half and a third of
            the time); the humanoid's 300 are its tuned value (450 measured
            worse).  The paper, too, spent 30 minutes on the spider and 70 on the
            humanoid.
        chunk: generations per compiled chunk (progress granularity) when there
            is no memetic step (another algorithm than the GA, or a memetic
            setting of 0); otherwise a chunk is ``memetic_every`` generations.
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
            individuals by ``memetic_steps`` Adam steps (0: never); a step is one
            evaluation of the cost and its gradient (:func:`~jaxpose.search.refine.refine`).
        final_refine_steps: Adam steps at the end (0: none) on the ``final_refine_top`` best
            individuals (the GA) or on the best point (other algorithms).  When
            ``final_refine_top == memetic_top`` (the default) the final refinement
            reuses the memetic step's compiled program.
        learning_rate: Adam learning rate (genome units).
        init_root_std: spread of the initial root translation genes around the
            cloud's centre (genome units).
        init_pca_fraction: fraction of the initial population whose root
            orientation aligns the model's principal axes (rest pose) with the
            cloud's, one of the four proper sign choices at random, then spun by a
            uniform angle about the most reliable of those axes (the major axis of
            an elongated model, else the normal; the other two are ambiguous under
            occlusion), and whose root puts the model's centre behind the cloud's
            centre (0: all uniform).
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
            refined best.  The budget grows with the number of islands.  Islands are
            restarts: each settles on one root orientation early (the trunk is
            searched first) and keeps it.
        halve_islands_at: fractions of the generations after which the worse half of
            the islands (by best cost) is replaced by copies of the better half
            (successive halving: many orientation hypotheses early, the budget on the
            promising ones later; a copy continues with its own random numbers).
            Each is rounded to the end of an epoch; ``()``: never.
        coarse_points: coarse-to-fine (GA only; 0: off): during the first
            ``coarse_until`` of the generations (rounded to the end of an epoch) the
            GA scores individuals on this many of the cloud's points only (whole
            blocks of ``objective.block`` points, spread over the cloud), then
            rescores its population on all of them and goes on with all of them.
            Gradient refinement always uses every point.
        coarse_until: see ``coarse_points``.
        tie_lengths: alike links (one orbit of the skeleton's symmetries,
            ``Skeleton.orbit``: a humanoid's two forearms, a spider's legs) get one
            length, the mean of their length genes, applied wherever genomes are made
            (the initial population, every generation's children, refinement, the
            result).  Off by default: on 32 rendered humanoid images it placed
            fewer links correctly (88.1% against 89.9% untied, one seed), as a
            branch swap or mutation of one limb's length then moves its mirror
            too.  For a robot known to be symmetric it keeps the result so.
        objective: the cost's settings.
    """

    algorithm: str = "ga"
    population: int = 64
    generations: int | None = None
    chunk: int = 25
    std_init: float = 0.15
    std_final: float = 0.01
    crossover_rate: float = 0.5
    mutation_rate: float = 0.15
    branch_mutation_rate: float = 0.3
    branch_reset_rate: float = 0.1
    elite_ratio: float = 0.25
    memetic_every: int = 25
    memetic_top: int = 4
    memetic_steps: int = 10
    final_refine_top: int = 4
    final_refine_steps: int = 100
    learning_rate: float = 0.01
    init_root_std: float = 0.1
    init_pca_fraction: float = 0.5
    init_pca_std: float = 0.02
    scale_window: float = 1.5
    islands: int = 32
    halve_islands_at: tuple[float, ...] = (1 / 3, 1 / 2, 2 / 3, 5 / 6)
    staged: float = 0.5
    coarse_points: int = 0
    coarse_until: float = 0.5
    tie_lengths: bool = False
    objective: ObjectiveConfig = field(default_factory=ObjectiveConfig)

    def __post_init__(self):  # a list (from JSON, say) would not be hashable
        object.__setattr__(self, "halve_islands_at", tuple(self.halve_islands_at))

    def validate(self) -> "FitConfig":
        if not isinstance(self.population, int) or self.population < 2:
            raise ConfigError(f"population must be an integer >= 2, got {self.population!r}")
        if self.generations is not None and (not isinstance(self.generations, int) or self.generations < 1):
            raise ConfigError(f"generations must be an integer >= 1 (or None: automatic), got {self.generations!r}")
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
        if not all(isinstance(f, (int, float)) and 0.0 < f < 1.0 for f in self.halve_islands_at):
            raise ConfigError(f"halve_islands_at must hold fractions in (0, 1), got {self.halve_islands_at!r}")
        if not isinstance(self.coarse_points, int) or self.coarse_points < 0:
            raise ConfigError(f"coarse_points must be an integer >= 0, got {self.coarse_points!r}")
        if self.coarse_points and self.algorithm != "ga":
            raise ConfigError(f"coarse_points works with the GA only, not {self.algorithm!r}")
        if not 0.0 < self.coarse_until < 1.0:
            raise ConfigError(f"coarse_until must lie in (0, 1), got {self.coarse_until}")
        if not isinstance(self.tie_lengths, bool):
            raise ConfigError(f"tie_lengths must be true or false, got {self.tie_lengths!r}")
        if not 0.0 <= self.staged <= 1.0:
            raise ConfigError(f"staged must lie in [0, 1], got {self.staged}")
        if not 0.0 <= self.init_pca_fraction <= 1.0:
            raise ConfigError(f"init_pca_fraction must lie in [0, 1], got {self.init_pca_fraction}")
        if not 0.0 < self.elite_ratio <= 1.0:
            raise ConfigError(f"elite_ratio must lie in (0, 1], got {self.elite_ratio}")
        if self.std_init <= 0 or self.std_final <= 0:
            raise ConfigError("std_init and std_final must be positive")
        obj = self.objective
        if not (obj.free_space_weight >= 0 and obj.collision_weight >= 0):
            raise ConfigError(f"objective weights must be >= 0, got free_space_weight {obj.free_space_weight}, "
                              f"collision_weight {obj.collision_weight}")
        if not 0 < obj.collision_margin <= 2:
            raise ConfigError(f"objective.collision_margin must lie in (0, 2], got {obj.collision_margin}")
        for name in ("memetic_every", "memetic_top", "memetic_steps", "final_refine_top", "final_refine_steps"):
            if getattr(self, name) < 0:
                raise ConfigError(f"{name} must be >= 0, got {getattr(self, name)}")
        return self

    def for_skeleton(self, skel: Skeleton) -> "FitConfig":
        """This config with ``generations`` chosen for ``skel`` when it is ``None``
        (:func:`auto_generations`); the search itself always runs a resolved config."""
        if self.generations is not None:
            return self
        return dataclasses.replace(self, generations=auto_generations(skel, self.epoch))

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
    """The search between compiled pieces.  With islands, every field but ``obs`` and
    ``bounds`` (the same for all islands, stored once) has a leading island axis.

    ``initial`` is the initial population; the first generation evaluates it (while
    ``objective_evaluations`` is 0, ``algo_state`` is a placeholder)."""

    algo_state: Any
    key: jax.Array
    obs: Observation
    bounds: Bounds
    objective_evaluations: jax.Array
    gradient_evaluations: jax.Array
    initial: jax.Array


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
    """``cost(genomes (P, D), blocks=None) -> (P,)`` (``blocks``: see :func:`data_cost`)."""

    pairs = collision_pairs(skel, config.objective.collision_margin) if config.objective.collision_weight > 0 else None

    def cost(genomes, blocks=None):
        poses = jax.vmap(partial(decode, skel, bounds))(genomes)
        links = jax.vmap(partial(forward_kinematics, skel))(poses)
        c = population_cost(obs, links.start, links.end, links.radius, config.objective, blocks, pairs)
        return jnp.where(jnp.isfinite(c), c, jnp.inf)

    return cost


def coarse_switch(config: FitConfig, n_points: int) -> int | None:
    """The generation at which a coarse-to-fine GA goes over to every point (the end of
    an epoch), or ``None`` when it scores every point throughout (``FitConfig.coarse_points``)."""
    if not config.coarse_points or _coarse_blocks(config, n_points) >= num_blocks(n_points, config.objective.block):
        return None
    E = config.epoch
    g = E * max(1, round(config.coarse_until * config.generations / E))
    return g if g < config.generations else None


def _coarse_blocks(config: FitConfig, n_points: int) -> int:
    B = min(config.objective.block, max(n_points, 1))
    return max(1, -(-config.coarse_points // B))


def _blocks_at(config: FitConfig, n_points: int, generation):
    """Blocks of points the GA scores at ``generation`` (``None``: all, the plain kernel)."""
    switch = coarse_switch(config, n_points)
    if switch is None:
        return None
    return jnp.where(generation < switch, _coarse_blocks(config, n_points),
                     num_blocks(n_points, config.objective.block))


def _rescore1(skel: Skeleton, config: FitConfig, st: SearchState) -> SearchState:
    """The GA's population and best so far scored anew on every point (coarse -> fine)."""
    state = st.algo_state
    both = jnp.concatenate([state.population, state.best_solution[None]])
    f = _population_cost_fn(skel, st.obs, st.bounds, config)(both)
    state = state.replace(fitness=f[:-1], best_fitness=f[-1])
    return st._replace(algo_state=state, objective_evaluations=st.objective_evaluations + both.shape[0])


def rescore_at_switch(skel: Skeleton, config: FitConfig, st: SearchState) -> SearchState:
    """At the coarse-to-fine switch (:func:`coarse_switch`), :func:`_rescore1` every island."""
    switch = coarse_switch(config, st.obs.cloud.points.shape[-2])
    if switch is None:
        return st
    gen = st.algo_state.generation_counter if config.islands == 1 else st.algo_state.generation_counter[0]
    return jax.lax.cond(gen == switch, lambda s: _per_island(config, partial(_rescore1, skel, config), s),
                        lambda s: s, st)


def _model_samples(skel: Skeleton) -> jax.Array:
    """Points along the rest-pose capsule axes at scale 1 (skeleton frame)."""
    links = forward_kinematics(skel, rest_pose(skel))
    t = jnp.linspace(0.0, 1.0, 8)[:, None, None]
    return (links.start[None] + t * (links.end - links.start)[None]).reshape(-1, 3)


class RestModel(NamedTuple):
    """The rest-pose model's shape at scale 1: centroid, principal axes, RMS spread,
    and the axis that orientation hypotheses spin about (:func:`aligned_root`)."""

    centre: jax.Array  # (3,)
    axes: jax.Array  # (3, 3) columns by decreasing variance
    spread: jax.Array  # ()
    spin_axis: jax.Array  # () int: 0 (the major axis) or 2 (the minor axis)


# An elongated model (major variance at least this many times the second) spins its
# orientation hypotheses about its major axis, a flat one about its normal.
ELONGATED = 2.0


def rest_model(skel: Skeleton) -> RestModel:
    """:class:`RestModel` of ``skel`` (one forward-kinematics pass of the rest pose)."""
    pts = _model_samples(skel)
    c, axes, var = _principal_axes(pts, jnp.ones(pts.shape[0]))
    spin = jnp.where(var[0] >= ELONGATED * var[1], 0, 2)
    return RestModel(c, axes, jnp.sqrt(jnp.mean(jnp.sum((pts - c) ** 2, -1)) + 1e-12), spin)


def _principal_axes(points: jax.Array, weights: jax.Array):
    """Weighted centroid, principal axes (columns) and variances, by decreasing variance."""
    wsum = jnp.maximum(jnp.sum(weights), 1e-12)
    c = jnp.sum(points * weights[:, None], 0) / wsum
    d = points - c
    cov = (d * weights[:, None]).T @ d / wsum + 1e-9 * jnp.eye(3)
    val, vec = jnp.linalg.eigh(cov)  # ascending eigenvalues
    return c, vec[:, ::-1], val[::-1]


def principal_axes(points: jax.Array, weights: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Weighted centroid and principal axes (columns, by decreasing variance) of points."""
    return _principal_axes(points, weights)[:2]


def matrix_rpy(R: jax.Array) -> jax.Array:
    """(roll, pitch, yaw) of ``R = Rz(yaw) Ry(pitch) Rx(roll)``; the inverse of ``rpy_matrix``."""
    pitch = jnp.arcsin(jnp.clip(-R[2, 0], -1.0, 1.0))
    return jnp.stack([jnp.arctan2(R[2, 1], R[2, 2]), pitch, jnp.arctan2(R[1, 0], R[0, 0])])


def aligned_root(flip, skel: Skeleton, obs: Observation, scale, rest: RestModel | None = None, spin=0.0):
    """A root pose ``(translation, rpy)`` that aligns the rest-pose model's principal
    axes with the cloud's, then turns it by ``spin`` radians about one of them.

    The sign of each axis is ambiguous: ``flip (2,)`` (booleans) flips the first two
    axes, the third follows, so the four choices are the four proper rotations.
    Only one axis is reliable in a single view, though: a surface seen from one
    side says little about the body's other two axes (on the humanoid tuning
    images the best of the four alignments was 5-90 degrees off the truth, median
    about 35; the best spin about the major axis 3-22 degrees).  So hypotheses
    spin about ``RestModel.spin_axis``: the major axis of an elongated model, the
    normal of a flat one.  The model's centroid lands half a mean link radius
    behind the cloud's centroid (the cloud only covers the surface facing the
    camera).  ``rest`` (:func:`rest_model`) may be passed to skip recomputing it.
    """
    rest = rest or rest_model(skel)
    m_c, M = rest.centre, rest.axes
    c_c, C = principal_axes(obs.cloud.points, obs.cloud.weights)
    s12 = jnp.where(flip, -1.0, 1.0)
    s3 = s12[0] * s12[1] * jnp.sign(jnp.linalg.det(C) * jnp.linalg.det(M))
    R = (C * jnp.concatenate([s12, s3[None]])[None]) @ M.T
    R = axis_angle_matrix(C[:, rest.spin_axis], spin) @ R
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
    root aligned with the cloud's principal axes instead, turned by a uniform angle
    about the most reliable one (:func:`aligned_root`)."""
    rest = rest or rest_model(skel)
    layout = genome_layout(skel)
    P, D = config.population, layout.size
    # one draw for everything (each random draw is a sizeable program to compile); the
    # root-translation and length genes are disjoint, so they share one normal array
    u, z = uniform_and_normal(key, (P, D + 3), D + 7)
    g = u[:, :D]
    names = layout.names
    root_t = np.array([n in ("root_tx", "root_ty", "root_tz") for n in names])
    scale_i = names.index("scale")
    is_len = np.array([n.endswith(".length") for n in names])
    g = jnp.where(root_t, 0.5 + config.init_root_std * z[:, :D], g)
    s0 = initial_scale(skel, obs, config, rest)
    s_lo, s_hi = bounds.lo[scale_i], bounds.hi[scale_i]
    s_gene = (s0 * jnp.exp(0.15 * z[:, D]) - s_lo) / jnp.maximum(s_hi - s_lo, 1e-9)
    g = g.at[:, scale_i].set(s_gene)
    rest_g = encode(skel, bounds, rest_pose(skel))
    g = jnp.where(is_len, rest_g + 0.1 * z[:, :D], g)
    n_pca = int(round(config.init_pca_fraction * P))
    if n_pca > 0:
        flips, spin = u[:n_pca, D : D + 2] < 0.5, 2.0 * jnp.pi * u[:n_pca, D + 2]
        t, rpy = jax.vmap(lambda f, a: aligned_root(f, skel, obs, s0, rest, a))(flips, spin)
        span = jnp.maximum(bounds.hi[:6] - bounds.lo[:6], 1e-9)
        root_g = (jnp.concatenate([t, rpy], 1) - bounds.lo[:6]) / span
        root_g = root_g + config.init_pca_std * z[:n_pca, D + 1 :]
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


def _length_orbits(skel: Skeleton) -> tuple[np.ndarray, np.ndarray]:
    """Genes of searched lengths that alike links share (``Skeleton.orbit``), and each
    one's orbit number: ``(genes (T,), orbit (T,))``, empty when there are none."""
    layout = genome_layout(skel)
    gene_of = {layout.link_of_gene[k]: k for k, n in enumerate(layout.names) if n.endswith(".length")}
    members: dict[int, list[int]] = {}
    for i, o in enumerate(skel.orbit):
        if i in gene_of:
            members.setdefault(o, []).append(gene_of[i])
    tied = [m for m in members.values() if len(m) > 1]
    genes = [g for m in tied for g in m]
    orbit = [k for k, m in enumerate(tied) for _ in m]
    return np.asarray(genes, np.int32), np.asarray(orbit, np.int32)


def _tie(skel: Skeleton, genomes):
    """Length genes of alike links (a humanoid's two forearms, a spider's legs) set to their mean."""
    genes, orbit = _length_orbits(skel)
    if genes.size == 0:
        return genomes
    one_hot = jnp.asarray(orbit[:, None] == np.arange(orbit.max() + 1)[None], genomes.dtype)
    mean = (genomes[..., genes] @ one_hot) / jnp.sum(one_hot, 0)
    return genomes.at[..., genes].set(mean[..., orbit])


def _lock(skel: Skeleton, config: FitConfig, bounds: Bounds, generation, genomes):
    """Locked genes (staged search) set to their rest values; with ``tie_lengths``
    the length genes of alike links set to their mean."""
    if config.tie_lengths:
        genomes = _tie(skel, genomes)
    if config.staged <= 0:
        return genomes
    rest = encode(skel, bounds, rest_pose(skel))
    return jnp.where(_unlocked(skel, config, generation), genomes, rest)


def _search_init1(obs: Observation, bounds: Bounds, rest: RestModel, skel: Skeleton, keys: jax.Array,
                  config: FitConfig) -> SearchState:
    """The initial population and a placeholder state of the algorithm: nothing is
    evaluated here (see :func:`_start`), so this program does not compile the cost.
    ``keys (3,)``: for the population, the algorithm's init, and the search."""
    algo, params = _make_algorithm(skel, config)
    k_pop, k_init, k_run = keys
    pop0 = _lock(skel, config, bounds, 0, initial_population(k_pop, skel, obs, bounds, config, rest))
    unknown = jnp.full(pop0.shape[:1], jnp.inf, pop0.dtype)
    state = _start(algo, params, k_init, pop0, unknown).replace(generation_counter=0)
    zero = jnp.asarray(0, jnp.int32)
    return SearchState(state, k_run, obs, bounds, zero, zero, pop0)


def _start(algo, params, key, pop0, fit0):
    """The algorithm's state after evaluating the initial population ``pop0`` (costs
    ``fit0``): a population-based algorithm (the GA, PSO, DE, ...) starts from it; a
    distribution-based one (hill climbing, CMA-ES, ...) at its best individual.
    This counts as the first generation."""
    if isinstance(algo, PopulationBasedAlgorithm):
        state = algo.init(key, pop0, fit0, params)
    else:
        best = jnp.argmin(jnp.where(jnp.isnan(fit0), jnp.inf, fit0))
        state = algo.init(key, pop0[best], params)
        state = state.replace(best_solution=pop0[best], best_fitness=fit0[best])
        if hasattr(state, "best_fitness_shaped"):  # hill climbing moves only to better points
            state = state.replace(best_solution_shaped=pop0[best], best_fitness_shaped=fit0[best])
    return state.replace(generation_counter=1)


def _refine_rows(skel: Skeleton, config: FitConfig, obs: Observation, bounds: Bounds, gen, cand, steps):
    """Adam-refine the rows of ``cand (m, D)``; genes locked at ``gen`` stay locked."""
    pop_cost = _population_cost_fn(skel, obs, bounds, config)
    return refine(lambda G: pop_cost(_lock(skel, config, bounds, gen, G)), cand, steps, config.learning_rate)


def _per_island(config: FitConfig, fn, st: SearchState, *args):
    """``fn(st, *args)`` for one island, vmapped over the leading island axis of ``st``
    and ``args`` when ``config.islands > 1``.  The observation and bounds are shared,
    not batched: every island reads the same cloud.  A :class:`SearchState` in
    ``fn``'s output (alone or in a tuple) gets them back."""
    if config.islands == 1:
        return fn(st, *args)
    return _vmap_shared(st.obs, st.bounds, lambda s, *a: fn(s._replace(obs=st.obs, bounds=st.bounds), *a),
                        st._replace(obs=None, bounds=None), *args)


def _vmap_shared(obs: Observation, bounds: Bounds, fn, *args):
    """``jax.vmap(fn)(*args)`` with ``obs`` and ``bounds`` left out of the batch: any
    :class:`SearchState` that ``fn`` returns gets them back unbatched."""
    out = jax.vmap(lambda *a: _map_states(fn(*a), lambda o: o._replace(obs=None, bounds=None)))(*args)
    return _map_states(out, lambda o: o._replace(obs=obs, bounds=bounds))


def _map_states(out, f):
    """``f`` applied to ``out`` if it is a :class:`SearchState`, or to the states in a tuple."""
    if isinstance(out, SearchState):
        return f(out)
    if type(out) is tuple:
        return tuple(_map_states(o, f) for o in out)
    return out


def _candidates(config: FitConfig, m: int, state):
    """The ``m`` fittest of the GA's population (``order``: their rows), or the best
    point of the other algorithms."""
    if config.algorithm == "ga":  # elitism keeps the best in the population
        order = jnp.argsort(state.fitness)[:m]
        return order, state.population[order]
    return jnp.zeros((1,), jnp.int32), state.best_solution[None]


def refine_top(skel: Skeleton, config: FitConfig, st: SearchState, m: int, steps):
    """Adam-refine every island's best candidates (:func:`_candidates`).  Returns
    ``(order, genomes, costs)`` (``order``: the candidates' rows in the population),
    with a leading island axis when there are islands.

    The islands' candidates are refined as one batch (every row's refinement is its
    own; the cloud is the same).  Genes locked at the current generation
    (``FitConfig.staged``) stay locked.  The step count is dynamic, so the memetic
    step and the final refinement share one compiled program when they refine the
    same number of candidates.
    """
    pick = partial(_candidates, config, m)
    order, cand = pick(st.algo_state) if config.islands == 1 else jax.vmap(pick)(st.algo_state)
    gen = st.algo_state.generation_counter.reshape(-1)[0]
    D = cand.shape[-1]
    g, f = _refine_rows(skel, config, st.obs, st.bounds, gen, cand.reshape(-1, D), steps)
    return order, g.reshape(cand.shape), f.reshape(cand.shape[:-1])


def _memetic_top(config: FitConfig) -> int:
    return min(config.memetic_top, config.population)


def _final_top(config: FitConfig) -> int:
    return min(config.final_refine_top, config.population) if config.algorithm == "ga" else 1


def _keep_better(g, f, best_g, best_f):
    """The best of refined rows ``g (m, D)``, ``f (m,)`` if it beats ``(best_g, best_f)``."""
    i = jnp.argmin(f)
    better = f[i] < best_f
    return jnp.where(better, g[i], best_g), jnp.where(better, f[i], best_f)


def _memetic_apply1(skel: Skeleton, config: FitConfig, st: SearchState, order, g, f) -> SearchState:
    """Write refined individuals back into the population (and the best so far)."""
    state = st.algo_state
    gen = state.generation_counter
    best_g, best_f = _keep_better(g, f, state.best_solution, state.best_fitness)
    lock = partial(_lock, skel, config, st.bounds, gen)
    state = state.replace(
        population=lock(state.population.at[order].set(g)),
        fitness=state.fitness.at[order].set(f),
        best_solution=lock(best_g),
        best_fitness=best_f,
    )
    grads = st.gradient_evaluations + g.shape[0] * config.memetic_steps
    return st._replace(algo_state=state, gradient_evaluations=grads)


def memetic_apply(skel: Skeleton, config: FitConfig, st: SearchState, refined, history):
    """Apply :func:`refine_top`'s result as the memetic step; the epoch's last
    history entry becomes the best cost after it."""
    st = _per_island(config, lambda s, o, g, f: _memetic_apply1(skel, config, s, o, g, f), st, *refined)
    return st, history.at[-1].set(jnp.min(st.algo_state.best_fitness))


def _island_map(config: FitConfig, fn):
    """``fn`` vmapped over the leading island axis when ``config.islands > 1``."""
    return fn if config.islands == 1 else jax.vmap(fn)


def _generations(skel: Skeleton, config: FitConfig, st: SearchState, length: int):
    """``length`` generations of every island.  The scan runs over generations and
    only the algorithm's ``ask`` and ``tell`` are vmapped over the islands: every
    island's children are scored in one call of the cost on ``(islands * P, D)``
    genomes (a vmapped scan would trace and batch the whole cost kernel, the
    larger program to compile)."""
    algo, params = _make_algorithm(skel, config)
    pop_cost = _population_cost_fn(skel, st.obs, st.bounds, config)
    n_points = st.obs.cloud.points.shape[0]
    unevaluated = st.objective_evaluations == 0  # this program starts the search
    lock = partial(_lock, skel, config, st.bounds)

    def ask1(state, key, initial, first):
        key, k_ask, k_tell = jax.random.split(key, 3)
        pop, asked = algo.ask(k_ask, state, params)
        return jnp.where(first, initial, lock(state.generation_counter, pop)), asked, key, k_tell

    def tell1(k_tell, pop, fitness, asked, first):
        told, _ = algo.tell(k_tell, pop, fitness, asked, params)
        started = _start(algo, params, k_tell, pop, fitness)
        return jax.tree_util.tree_map(lambda a, b: jnp.where(first, a, b), started, told)

    def generation(carry, i):
        state, key = carry
        first = unevaluated & (i == 0)
        pop, asked, key, k_tell = _island_map(config, ask1)(state, key, st.initial, first)
        gen = state.generation_counter.reshape(-1)[0]
        fitness = pop_cost(pop.reshape(-1, pop.shape[-1]), _blocks_at(config, n_points, gen))
        state = _island_map(config, tell1)(k_tell, pop, fitness.reshape(pop.shape[:-1]), asked, first)
        return (state, key), jnp.min(state.best_fitness)

    (state, key), hist = jax.lax.scan(generation, (st.algo_state, st.key), jnp.arange(length))
    evals = st.objective_evaluations + length * config.population
    return st._replace(algo_state=state, key=key, objective_evaluations=evals), hist


def search_init(cloud: Cloud, skel: Skeleton, key: jax.Array, config: FitConfig) -> SearchState:
    """Initial search state (with a leading island axis when ``config.islands > 1``).
    The pieces take a resolved config (``config.for_skeleton(skel)``: the generations set)."""
    if config.generations is None:
        raise ConfigError("generations is None (automatic): resolve it with config.for_skeleton(skeleton) "
                          "before calling the search's pieces")
    obs = observe(cloud, config.objective)
    rest = rest_model(skel)
    bounds = search_bounds(skel, obs, config, rest)
    if config.islands == 1:
        return _search_init1(obs, bounds, rest, skel, jax.random.split(key, 3), config)
    # every island's keys in one draw (each draw is a sizeable program to compile)
    return _vmap_shared(obs, bounds, lambda k: _search_init1(obs, bounds, rest, skel, k, config),
                        jax.random.split(key, (config.islands, 3)))


def halving_generations(config: FitConfig) -> tuple[int, ...]:
    """The generations after which the islands are halved (``FitConfig.halve_islands_at``,
    each rounded to the nearest end of an epoch; none at the very end)."""
    E, G = config.epoch, config.generations
    if config.islands < 2:
        return ()
    at = {E * max(1, round(f * G / E)) for f in config.halve_islands_at}
    return tuple(sorted(g for g in at if g < G))


def halve_islands(config: FitConfig, st: SearchState) -> SearchState:
    """The worse half of the islands (by best cost) takes over the populations of the
    better half, when the generation count is one of :func:`halving_generations`.

    Only the evolutionary state is copied: every island keeps its random key (so a
    copy and its original go separate ways from here) and its evaluation counts."""
    when = halving_generations(config)
    if not when:
        return st
    state = st.algo_state
    order = jnp.argsort(state.best_fitness)
    n, half = config.islands, config.islands // 2
    source = jnp.arange(n).at[order[n - half :]].set(order[:half])
    now = jnp.any(state.generation_counter[0] == jnp.asarray(when))
    copied = jax.tree_util.tree_map(lambda x: jnp.where(now, x[source], x), state)
    return st._replace(algo_state=copied)


def search_generations(skel: Skeleton, config: FitConfig, st: SearchState, length: int):
    """:func:`halve_islands` (the previous epoch's memetic step included), then run
    ``length`` generations (no refinement).  Returns the new state and the best cost
    (over all islands) after each generation ``(length,)``."""
    st = rescore_at_switch(skel, config, halve_islands(config, st))
    return _generations(skel, config, st, length)


def search_epoch(skel: Skeleton, config: FitConfig, st: SearchState, length: int,
                 _pieces=(search_generations, refine_top, memetic_apply)):
    """Run ``length`` generations, then a memetic refinement when it is on.  Returns
    the new state and the best cost (over all islands) after each generation.
    (``_pieces``: the three steps, replaced by their compiled forms in :class:`Fitter`.)"""
    generations, refine_fn, apply_fn = _pieces
    st, hist = generations(skel, config, st, length)
    if config.memetic_on:
        refined = refine_fn(skel, config, st, _memetic_top(config), jnp.int32(config.memetic_steps))
        st, hist = apply_fn(skel, config, st, refined, hist)
    return st, hist


def evaluation_counts(st: SearchState) -> tuple[jax.Array, jax.Array]:
    """Objective and gradient evaluations so far, summed over islands."""
    return jnp.sum(st.objective_evaluations), jnp.sum(st.gradient_evaluations)


def _final_refine_on(config: FitConfig) -> bool:
    return config.final_refine_steps > 0 and config.final_refine_top > 0


def final_refine(skel: Skeleton, config: FitConfig, st: SearchState, _refine_fn=refine_top):
    """The final refinement's candidates refined (:func:`refine_top`), or ``None`` when off."""
    if _final_refine_on(config):
        return _refine_fn(skel, config, st, _final_top(config), jnp.int32(config.final_refine_steps))
    return None


def _finish1(config: FitConfig, st: SearchState, refined):
    """One island's best: ``(genome, cost, evaluations, gradients)``."""
    state = st.algo_state
    best_g, best_f = state.best_solution, state.best_fitness
    evals, grads = st.objective_evaluations, st.gradient_evaluations
    if refined is not None:
        _, g, f = refined
        grads = grads + g.shape[0] * config.final_refine_steps
        best_g, best_f = _keep_better(g, f, best_g, best_f)
    return best_g, best_f, evals, grads


def search_result(cloud: Cloud, skel: Skeleton, config: FitConfig, st: SearchState, history, refined) -> FitResult:
    """The :class:`FitResult` of a finished search, given :func:`final_refine`'s output."""
    if config.islands == 1:
        best_g, best_f, evals, grads = _finish1(config, st, refined)
    else:
        g, f, e, gr = _per_island(config, lambda s, r: _finish1(config, s, r), st, refined)
        i = jnp.argmin(f)
        best_g, best_f, evals, grads = g[i], f[i], jnp.sum(e), jnp.sum(gr)
    bounds = st.bounds
    best_g = jnp.clip(best_g, 0.0, 1.0)  # evosax strategies sample unbounded; decode clips the same way
    if config.tie_lengths:  # the projection every generation applies, also to the returned best
        best_g = _tie(skel, best_g)
    pose = decode(skel, bounds, best_g)
    links = forward_kinematics(skel, pose)
    n_dist = (evals + grads).astype(jnp.float32) * cloud.points.shape[0] * skel.num_links
    return FitResult(pose, best_g, links, best_f, history, evals, grads, n_dist, jnp.asarray(0.0, jnp.float32))


def search_finish(cloud: Cloud, skel: Skeleton, config: FitConfig, st: SearchState, history) -> FitResult:
    """Final refinement, then the best individual over all islands as a :class:`FitResult`."""
    return search_result(cloud, skel, config, st, history, final_refine(skel, config, st))


def _epochs(config: FitConfig) -> tuple[int, int, int]:
    E = config.epoch
    return E, config.generations // E, config.generations % E


def fit(cloud: Cloud, skeleton: Skeleton, key: jax.Array, config: FitConfig = FitConfig()) -> FitResult:
    """Search ``skeleton``'s parameters that best explain ``cloud`` (camera frame).

    Pure and jit-compatible (``config`` is static); vmappable over clouds and keys::

        fit_jit = jax.jit(fit, static_argnames="config")
        batch = jax.vmap(fit_jit, in_axes=(0, None, 0, None))(clouds, skel, keys, config)
    """
    config = config.validate().for_skeleton(skeleton)
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


# the programs that run once or a few times per fit compile with options that compile
# faster (same run time, numbers equal up to round-off: see jaxpose/_xla_flags.py); the generation loop
# keeps XLA's defaults, which run it faster
_once = fast_compile_options()
_init_jit = jax.jit(search_init, static_argnames="config", compiler_options=_once)
_generations_jit = jax.jit(search_generations, static_argnames=("config", "length"))
_refine_jit = jax.jit(refine_top, static_argnames=("config", "m"), compiler_options=_once)
_memetic_apply_jit = jax.jit(memetic_apply, static_argnames="config", compiler_options=_once)
_result_jit = jax.jit(search_result, static_argnames="config", compiler_options=_once)


def _epoch_jit(skel: Skeleton, config: FitConfig, st: SearchState, length: int):
    """:func:`search_epoch` in compiled pieces: the generations, then the memetic
    refinement as its own program (which the final refinement reuses)."""
    return search_epoch(skel, config, st, length, (_generations_jit, _refine_jit, _memetic_apply_jit))


def _finish_jit(cloud: Cloud, skel: Skeleton, config: FitConfig, st: SearchState, history) -> FitResult:
    """:func:`search_finish` in compiled pieces (the refinement shared with the memetic step)."""
    return _result_jit(cloud, skel, config, st, history, final_refine(skel, config, st, _refine_jit))


class _Programs:
    """The compiled pieces of one fit configuration (:func:`compile_pieces`), run as
    :func:`_init_jit`, :func:`_epoch_jit` and :func:`_finish_jit` run them."""

    def __init__(self, init, generations, refine, apply, result):
        self._init, self._generations, self._refine = init, generations, refine
        self._apply, self._result = apply, result

    def init(self, cloud: Cloud, skel: Skeleton, key: jax.Array) -> SearchState:
        return self._init(cloud, skel, key)

    def epoch(self, skel: Skeleton, config: FitConfig, st: SearchState, length: int):
        return search_epoch(skel, config, st, length, (
            lambda sk, c, s, n: self._generations[n](sk, s),
            lambda sk, c, s, m, steps: self._refine[m](sk, s, steps),
            lambda sk, c, s, refined, h: self._apply[h.shape[0]](sk, s, refined, h)))

    def finish(self, cloud: Cloud, skel: Skeleton, config: FitConfig, st: SearchState, history) -> FitResult:
        refined = final_refine(skel, config, st, lambda sk, c, s, m, steps: self._refine[m](sk, s, steps))
        return self._result(cloud, skel, st, history, refined)


def compile_pieces(cloud: Cloud, skel: Skeleton, key: jax.Array, config: FitConfig, workers: int = 2) -> _Programs:
    """Trace and compile every piece of a fit ahead of time, XLA compiling one piece
    in a worker thread while Python traces the next (XLA releases the interpreter
    lock while it compiles).  The pieces are exactly the ``_*_jit`` functions'
    programs; only the order of the work changes (humanoid, 2-core VM: about a
    fifth less wall time than compiling on first call)."""
    E, n_full, rem = _epochs(config)
    lengths = sorted(set(([E] if n_full else []) + ([rem] if rem else [])))
    pool = ThreadPoolExecutor(max_workers=workers)
    try:
        low = _init_jit.lower(cloud, skel, key, config=config)
        init, st = pool.submit(low.compile), low.out_info
        gens, hist = {}, {}
        for n in lengths:
            low = _generations_jit.lower(skel, config, st, length=n)
            gens[n], hist[n] = pool.submit(low.compile), low.out_info[1]
        steps = jax.ShapeDtypeStruct((), jnp.int32)
        tops = ([_memetic_top(config)] if config.memetic_on else []) + (
            [_final_top(config)] if _final_refine_on(config) else [])
        refine, refined = {}, {}
        for m in sorted(set(tops)):
            low = _refine_jit.lower(skel, config, st, m, steps)
            refine[m], refined[m] = pool.submit(low.compile), low.out_info
        apply = {}
        if config.memetic_on:
            m = _memetic_top(config)
            for n in lengths:
                apply[n] = pool.submit(_memetic_apply_jit.lower(skel, config, st, refined[m], hist[n]).compile)
        final = refined[_final_top(config)] if _final_refine_on(config) else None
        history = jax.ShapeDtypeStruct((config.generations,), jnp.float32)
        result = pool.submit(_result_jit.lower(cloud, skel, config, st, history, final).compile)
        done = lambda d: {k: f.result() for k, f in d.items()}  # noqa: E731
        return _Programs(init.result(), done(gens), done(refine), done(apply), result.result())
    finally:  # an error or Ctrl-C does not wait for the compilations still queued
        pool.shutdown(wait=False, cancel_futures=True)


def _signature(cloud: Cloud, skel: Skeleton, key: jax.Array, config: FitConfig):
    """What a compiled fit depends on: the config and the arguments' structure and types."""
    leaves, tree = jax.tree_util.tree_flatten((cloud, skel, key))
    return config, tree, tuple((x.shape, x.dtype) if hasattr(x, "dtype") else type(x) for x in leaves)


# compiled fits by signature, most recently used last (a few configurations at a time)
_PROGRAMS: OrderedDict = OrderedDict()
_MAX_PROGRAMS = 8


def _programs(cloud: Cloud, skel: Skeleton, key: jax.Array, config: FitConfig) -> _Programs:
    """The compiled pieces for this fit (``cloud``: float32, see :func:`_float32`), from
    the cache or compiled now."""
    sig = _signature(cloud, skel, key, config)
    if sig in _PROGRAMS:
        _PROGRAMS.move_to_end(sig)
    else:
        _PROGRAMS[sig] = compile_pieces(cloud, skel, key, config)
        while len(_PROGRAMS) > _MAX_PROGRAMS:
            _PROGRAMS.popitem(last=False)
    return _PROGRAMS[sig]


def _float32(cloud: Cloud) -> Cloud:
    return Cloud(jnp.asarray(cloud.points, jnp.float32), jnp.asarray(cloud.weights, jnp.float32))


class Fitter:
    """Run :func:`fit`'s steps one compiled chunk at a time, for progress reports.

    ``progress(generation, best_cost, evaluations)`` is called after every chunk.
    The pieces are compiled ahead of the first fit of a configuration and cloud size
    (:func:`compile_pieces`) and reused by later fits of the same signature.
    """

    def __init__(self, skeleton: Skeleton, config: FitConfig = FitConfig()):
        self.skeleton = skeleton
        self.config = config.validate().for_skeleton(skeleton)  # generations resolved

    def run(self, cloud: Cloud, key: jax.Array, progress=None) -> FitResult:
        cloud = _float32(cloud)
        t0 = time.perf_counter()
        skel, config = self.skeleton, self.config
        programs = _programs(cloud, skel, key, config)
        st = programs.init(cloud, skel, key)
        E, n_full, rem = _epochs(config)
        hists, gen = [], 0
        for length in [E] * n_full + ([rem] if rem else []):
            st, h = programs.epoch(skel, config, st, length)
            hists.append(h)
            gen += length
            if progress is not None:
                progress(gen, float(h[-1]), int(sum(evaluation_counts(st))))
        res = jax.block_until_ready(programs.finish(cloud, skel, config, st, jnp.concatenate(hists)))
        return res._replace(wall_time=jnp.asarray(time.perf_counter() - t0, jnp.float32))


def fit_cloud(cloud: Cloud, skeleton: Skeleton, seed: int = 0, config: FitConfig = FitConfig(),
              progress=None) -> FitResult:
    """Convenience: :class:`Fitter` with an integer seed; returns NumPy-friendly results."""
    return Fitter(skeleton, config).run(cloud, jax.random.key(seed), progress)
