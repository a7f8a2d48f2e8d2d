"""The search's settings: :class:`FitConfig` (static: shapes and schedules, one
compiled program each) and :class:`FitParams` (traced: the rates and weights, so
that one compiled program serves every value; evosax's constructor/``Params`` split).

Why each default is what it is: docs/search.md.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import jax.numpy as jnp
from flax import struct

from ..errors import ConfigError, require_finite, require_integer
from ..genome import genome_layout
from ..objective import ObjectiveConfig
from ..skeleton import Skeleton
from .baselines import evosax_strategy

GENERATIONS_PER_GENE = 4
GENERATIONS_RANGE = (100, 300)


def auto_generations(skel: Skeleton, epoch: int = 25) -> int:
    """The default number of generations for ``skel``: ``GENERATIONS_PER_GENE`` per
    searched gene, clipped to ``GENERATIONS_RANGE``, rounded to whole epochs (a
    shorter last epoch is one more program to compile)."""
    lo, hi = GENERATIONS_RANGE
    g = min(hi, max(lo, GENERATIONS_PER_GENE * genome_layout(skel).size))
    return int(epoch * max(1, round(g / epoch)))


# FitConfig's fields that are traced (FitParams), and ObjectiveConfig's.
TRACED = ("crossover_rate", "mutation_rate", "branch_mutation_rate", "branch_reset_rate", "learning_rate",
          "init_root_std", "init_pca_std", "staged")
TRACED_OBJECTIVE = ("sigma_factor", "free_space_weight", "collision_weight")


@struct.dataclass
class FitParams:
    """The settings a compiled fit takes as traced numbers (``float32`` scalars; ``root_rpy`` ``(3,)``).

    Made from a config by :meth:`FitConfig.params`; see :class:`FitConfig` for
    their meaning.  A weight of exactly 0 leaves its term out of the program, so it
    is a static choice: only positive weights are traced."""

    crossover_rate: jnp.ndarray
    mutation_rate: jnp.ndarray
    branch_mutation_rate: jnp.ndarray
    branch_reset_rate: jnp.ndarray
    learning_rate: jnp.ndarray
    init_root_std: jnp.ndarray
    init_pca_std: jnp.ndarray
    staged: jnp.ndarray
    sigma_factor: jnp.ndarray
    free_space_weight: jnp.ndarray
    collision_weight: jnp.ndarray
    root_rpy: jnp.ndarray
    """``(3,)``: with ``root_window > 0`` the root's orientation is searched as a turn of at most
    ``root_window`` radians (about each axis) from this one (a turn search, :attr:`FitConfig.turns`,
    :func:`~jaxpose.genome.held_bounds`); no config field sets them."""
    root_window: jnp.ndarray
    """Half-width (radians) of that window; 0: the root's orientation is free."""


@dataclass(frozen=True)
class FitConfig:
    """Search settings (hashable), each documented below its field.

    The rates, ``learning_rate``, the initial spreads, ``staged`` and the objective's
    ``sigma_factor`` and positive weights are traced (:class:`FitParams`): changing
    them reuses the compiled search (so the portfolio's searches share one).  See docs/search.md.
    """

    algorithm: str = "ga"
    """``"ga"`` (branch-swap GA), ``"hc"`` (hill climbing) or the name of any evosax
    strategy (e.g. ``"cma_es"``)."""
    population: int = 64
    """Individuals evaluated per generation (per island)."""
    generations: int | None = None
    """Generations, the first of which evaluates the initial population; ``None``:
    :func:`auto_generations` (:meth:`for_skeleton`)."""
    epoch: int = 25
    """Generations per epoch, the unit the search is compiled and reported in; the
    GA's memetic step ends every epoch."""
    std_init: float = 0.15
    """Mutation / sampling step (normalised genome units) at the start, decayed
    exponentially over the generations to ``std_final``."""
    std_final: float = 0.01
    """Mutation / sampling step at the end."""
    crossover_rate: float = 0.5
    """Probability that a child takes a subtree from a second parent."""
    mutation_rate: float = 0.15
    """Per-gene mutation probability."""
    branch_mutation_rate: float = 0.3
    """Probability that a child mutates one whole subtree instead."""
    branch_reset_rate: float = 0.1
    """Probability that a child then draws one random subtree's genes anew (a jump
    out of a local optimum at any step size)."""
    elite_ratio: float = 0.25
    """Fraction of the population that may become parents."""
    memetic_top: int = 4
    """At the end of every epoch (GA only) this many best individuals take
    ``memetic_steps`` Adam steps."""
    memetic_steps: int = 10
    """Adam steps of the memetic step (0: no memetic step)."""
    memetic_hops: int = 0
    """Limb hops (GA only): in every memetic step each island also refines this many
    copies of its best in which one random subtree's joint angles (or the root's
    orientation) are drawn anew; they replace the island's worst individuals, so a
    limb caught in a wrong basin can jump to another and settle there (docs/search.md,
    "Limb hops")."""
    final_hops: int = 0
    """Limb hops of each island's best in the final refinement (as ``memetic_hops``)."""
    limb_sweep: int = 24
    """Limb sweep after the search (0: off): every link's subtree searched again, one
    after another, with the rest of the body held, by a GA of ``population``
    individuals for this many generations, then Adam (docs/search.md, "Limb sweep")."""
    pivot_sweep: int = 24
    """Pivot sweep after the search, before the limb sweep (0: off): for every body,
    its subtree held where it is and the rest of the body searched again around it
    (the root pose following), as ``limb_sweep`` (docs/search.md, "Pivot sweep")."""
    final_refine_top: int = 4
    """How many best individuals of the GA take ``final_refine_steps`` Adam steps at
    the end (other algorithms: their best point)."""
    final_refine_steps: int = 100
    """Adam steps at the end (0: none)."""
    learning_rate: float = 0.01
    """Adam learning rate (genome units)."""
    init_root_std: float = 0.1
    """Spread of the initial root translation genes around the cloud's centre."""
    init_pca_fraction: float = 0.5
    """Fraction of the initial population whose root aligns the model's principal
    axes with the cloud's, spun about the most reliable one."""
    init_pca_std: float = 0.02
    """Noise on those individuals' root genes."""
    scale_window: float = 1.5
    """The scale is searched within ``s0 / w .. s0 * w`` of the cloud's spread over
    the model's (0: the skeleton's range alone)."""
    scale: float | None = None
    """The subject's global scale when it is known (``None``: searched, near the cloud's spread
    over the model's).  A robot file's model has its robot's size: ``1``.  A folded pose
    spreads less than the rest pose the estimate assumes, and the search may settle on a
    smaller body (docs/search.md, "Known scale")."""
    islands: int = 32
    """Independent sub-populations searched side by side (vmapped)."""
    halve_islands_at: tuple[float, ...] = (1 / 3, 1 / 2, 2 / 3, 5 / 6)
    """Fractions of the generations after which the worse half of the islands takes
    over the better half's populations (successive halving)."""
    halve_niche_deg: float = 0.0
    """Niches in the halving (0: off): an island whose root orientation is more than
    this many degrees from that of every better island leads a niche, and leaders are
    kept before the rest, so one orientation cannot take every island early."""
    staged: float = 0.5
    """Trunk before limbs: links unlock level by level down the tree during the
    first ``staged`` fraction of the generations (0: all at once)."""
    staged_alternatives: tuple[float, ...] = (0.0,)
    """A portfolio of searches: after the search, one more for each value here, with
    ``staged`` set to it and a key of its own (the same compiled programs); the
    cheapest answer of all is the fit's.  Staging places natural poses better and
    misleads on folded and crossed limbs, where the search without it finds the pose
    (docs/search.md, "Portfolio"); ``()``: one search."""
    turns: int = 1
    """Turn searches (0-3; default 1, about the spin axis: the front/back turn): after the
    portfolio, its cheapest answer's root orientation turned half a turn about each of
    the model's principal axes (the spin axis first, :func:`~jaxpose.search.init.turned_roots`)
    and searched again from each, unstaged, the root's orientation held within
    ``turn_window`` of it; the cheapest answer of all is the fit's.  A whole body turned
    the wrong way round is a basin the other searches rarely leave (docs/search.md,
    "Turn searches")."""
    restarts: int = 1
    """Restarts: the whole fit (the portfolio, then its turn searches) run this many times, each
    time with keys of its own, the cheapest answer of all kept.  More independent search places
    more limbs of hard poses, at that many times the time (docs/search.md, "Restarts")."""
    restart_apart: float = 0.0
    """Adaptive restarts (0: off, every restart runs): a restart after the first runs only when
    the answers so far disagree, the cheapest and the next cheapest lying further apart than
    this fraction of the cloud's spread (:func:`~jaxpose.search.loop.answers_apart`: link ends
    matched within symmetry orbits).  Searches that agree have likely found the basin; searches
    that do not are worth another round (docs/search.md, "Adaptive restarts")."""
    turn_window: float = 0.6
    """Half-width (radians, about each axis) of the turn from its held orientation that each turn search allows."""
    coarse_points: int = 0
    """Coarse-to-fine (GA only; 0: off): score on this many points only, until
    ``coarse_until`` of the generations."""
    coarse_until: float = 0.5
    """The fraction of the generations scored on ``coarse_points``."""
    tie_lengths: bool = False
    """Alike links (one orbit of the skeleton's symmetries) share one length."""
    objective: ObjectiveConfig = field(default_factory=ObjectiveConfig)
    """The cost's settings."""

    def __post_init__(self):  # a list (from JSON, say) would not be hashable
        object.__setattr__(self, "halve_islands_at", tuple(self.halve_islands_at))
        if isinstance(self.staged_alternatives, (list, tuple)):
            object.__setattr__(self, "staged_alternatives", tuple(self.staged_alternatives))

    def validate(self) -> "FitConfig":
        """Raise :class:`ConfigError` naming the first impossible setting; return ``self``."""
        if any(getattr(self, n) is None for n in TRACED):
            raise ConfigError("this config is a static one (FitConfig.static(): its traced settings read None); "
                              "a fit needs the full FitConfig")

        def within(name, lo, hi, lo_open=False, hi_open=False):
            v = require_finite(name, getattr(self, name))
            if not ((lo < v if lo_open else lo <= v) and (v < hi if hi_open else v <= hi)):
                raise ConfigError(f"{name} must lie in {'(' if lo_open else '['}{lo:g}, {hi:g}{')' if hi_open else ']'}"
                                  f", got {v!r}")

        require_integer("population", self.population, 2)
        if self.generations is not None:
            require_integer("generations", self.generations, 1)
        require_integer("islands", self.islands, 1)
        require_integer("epoch", self.epoch, 1)
        if self.algorithm not in ("ga", "hc"):
            evosax_strategy(self.algorithm)
        for name in ("crossover_rate", "mutation_rate", "branch_mutation_rate", "branch_reset_rate",
                     "init_pca_fraction", "staged"):
            within(name, 0.0, 1.0)
        within("elite_ratio", 0.0, 1.0, lo_open=True)
        within("coarse_until", 0.0, 1.0, lo_open=True, hi_open=True)
        for name in ("std_init", "std_final", "learning_rate"):
            if not require_finite(name, getattr(self, name)) > 0:
                raise ConfigError(f"{name} must be > 0, got {getattr(self, name)!r}")
        for name in ("init_root_std", "init_pca_std"):
            if not require_finite(name, getattr(self, name)) >= 0:
                raise ConfigError(f"{name} must be >= 0, got {getattr(self, name)!r}")
        if self.scale is not None and not require_finite("scale", self.scale) > 0:
            raise ConfigError(f"scale must be > 0 (or left unset: searched), got {self.scale!r}")
        if self.scale_window != 0 and not require_finite("scale_window", self.scale_window) > 1.0:
            raise ConfigError(f"scale_window must be > 1 (or 0 for the skeleton's range), got {self.scale_window}")
        if not all(isinstance(f, (int, float)) and 0.0 < f < 1.0 for f in self.halve_islands_at):
            raise ConfigError(f"halve_islands_at must hold fractions in (0, 1), got {self.halve_islands_at!r}")
        within("halve_niche_deg", 0.0, 180.0)
        if not isinstance(self.staged_alternatives, tuple) or not all(
                isinstance(v, (int, float)) and not isinstance(v, bool) and 0.0 <= v <= 1.0
                for v in self.staged_alternatives):
            raise ConfigError(f"staged_alternatives must hold fractions in [0, 1], got {self.staged_alternatives!r}")
        require_integer("turns", self.turns, 0)
        require_integer("restarts", self.restarts, 1)
        if not require_finite("restart_apart", self.restart_apart) >= 0:
            raise ConfigError(f"restart_apart must be >= 0 (0: every restart runs), got {self.restart_apart!r}")
        if self.restart_apart and self.round_searches < 2:
            raise ConfigError("restart_apart compares a round's answers: it needs two searches a round "
                              "(staged_alternatives or turns), got one")
        if self.turns > 3:
            raise ConfigError(f"turns must be 0-3 (one per principal axis), got {self.turns}")
        within("turn_window", 0.0, float(jnp.pi), lo_open=True)
        require_integer("coarse_points", self.coarse_points, 0)
        if self.coarse_points and self.algorithm != "ga":
            raise ConfigError(f"coarse_points works with the GA (algorithm 'ga') only, not {self.algorithm!r}")
        if not isinstance(self.tie_lengths, bool):
            raise ConfigError(f"tie_lengths must be true or false, got {self.tie_lengths!r}")
        for name in ("memetic_top", "memetic_steps", "memetic_hops", "final_hops", "limb_sweep", "pivot_sweep",
                     "final_refine_top", "final_refine_steps"):
            require_integer(name, getattr(self, name), 0)
        self.objective.validate()
        return self

    def for_skeleton(self, skel: Skeleton) -> "FitConfig":
        """This config with ``generations`` chosen for ``skel`` when it is ``None``
        (:func:`auto_generations`); the search itself always runs a resolved config."""
        if self.generations is not None:
            return self
        return dataclasses.replace(self, generations=auto_generations(skel, self.epoch))

    @property
    def memetic_on(self) -> bool:
        return self.algorithm == "ga" and self.memetic_top > 0 and self.memetic_steps > 0

    @property
    def portfolio(self) -> int:
        """Searches of the portfolio: the search and its :attr:`staged_alternatives`."""
        return 1 + len(self.staged_alternatives)

    @property
    def round_searches(self) -> int:
        """Searches of one round (one restart): the portfolio's, then the :attr:`turns`."""
        return self.portfolio + self.turns

    @property
    def searches(self) -> int:
        """Searches a fit runs: one round's, :attr:`restarts` times."""
        return self.round_searches * self.restarts

    def search_params(self, params: FitParams) -> list[FitParams]:
        """The traced settings of each search of the portfolio (``params``, then one per alternative)."""
        return [params] + [params.replace(staged=jnp.asarray(v, jnp.float32)) for v in self.staged_alternatives]

    @property
    def final_refine_on(self) -> bool:
        return self.final_refine_steps > 0 and self.final_refine_top > 0

    @property
    def memetic_count(self) -> int:
        """Individuals each island refines in a memetic step."""
        return min(self.memetic_top, self.population)

    @property
    def final_count(self) -> int:
        """Individuals each island refines at the end."""
        return min(self.final_refine_top, self.population) if self.algorithm == "ga" else 1

    @property
    def memetic_rows(self) -> tuple[int, int]:
        """What each island refines in a memetic step: ``(best individuals, limb hops)``;
        the hops replace the worst individuals, so together they fit in the population."""
        top = self.memetic_count
        return top, min(self.memetic_hops, self.population - top)

    @property
    def final_rows(self) -> tuple[int, int]:
        """What each island refines at the end: ``(best individuals, limb hops)``."""
        top = self.final_count
        return top, (min(self.final_hops, self.population - top) if self.algorithm == "ga" else 0)

    @property
    def epoch_lengths(self) -> tuple[int, ...]:
        """The generations of every epoch of a resolved config (the last may be shorter)."""
        E, G = self.epoch, self.generations
        return (E,) * (G // E) + ((G % E,) if G % E else ())

    def params(self) -> FitParams:
        """The traced settings of this config."""
        obj = self.objective
        values = {n: getattr(self, n) for n in TRACED} | {n: getattr(obj, n) for n in TRACED_OBJECTIVE}
        return FitParams(**{n: jnp.asarray(v, jnp.float32) for n, v in values.items()},
                         root_rpy=jnp.zeros(3, jnp.float32), root_window=jnp.asarray(0.0, jnp.float32))

    def static(self) -> "FitConfig":
        """This config without its traced settings: what a compiled search depends on.
        Traced fields read ``None``; a zero weight stays 0 (its term is left out)."""
        obj = self.objective
        weights = {n: (None if getattr(obj, n) else 0.0) for n in ("free_space_weight", "collision_weight")}
        # the turn searches and the restarts run the same programs (a turn's window is traced)
        return dataclasses.replace(self, **dict.fromkeys(TRACED), turns=0, turn_window=None, restarts=1,
                                   restart_apart=0.0, objective=dataclasses.replace(obj, sigma_factor=None, **weights))

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)
