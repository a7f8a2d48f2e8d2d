"""The tracker's settings (:class:`TrackConfig`, static: one compiled step each).

Why each default is what it is: docs/tracking.md.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

from ..errors import ConfigError, require_finite, require_integer
from ..search import FitConfig
from ..skeleton import Skeleton


@dataclass(frozen=True)
class TrackConfig:
    """Tracking settings (hashable), each documented below its field."""

    fit: FitConfig = field(default_factory=FitConfig)
    """The global search: frame 0, the first frame after a lost one, recovery and rechecks.
    Its objective (and traced weights) also score the tracked frames."""
    population: int = 32
    """Individuals per generation of the local search around the prediction."""
    generations: int = 4
    """Generations of the local search (the first evaluates the population sampled
    around the prediction)."""
    std: float = 0.02
    """The local search's mutation step at its start (genome units of the local
    bounds), decayed to ``std_final``."""
    std_final: float = 0.005
    """The local search's mutation step at its end."""
    branch_reset_rate: float = 0.02
    """Probability that a child of the local search draws one subtree anew (a limb
    jumping to another place)."""
    sweep_limbs: int = 0
    """Limbs (subtrees, jaxpose.search.sweep.sweep_masks) searched anew in every tracked frame,
    in turn over the frames: a small GA over the limb's joint angles from uniform draws,
    the rest held, kept when cheaper (0: off, the default: on held-out sequences it
    changed the humanoid's accuracy by -1.2 to +1.7 points at 3x the frame time,
    docs/tracking.md)."""
    sweep_generations: int = 6
    """Generations of each swept limb's GA (``population`` individuals)."""
    sweep_steps: int = 10
    """Adam steps that polish each swept limb's best 2 (``search.sweep.SWEEP_REFINE_TOP``;
    0: none; none either when the global search's final refinement is off, ``--no-refine``)."""
    refine_top: int = 2
    """How many of the local search's best individuals take ``refine_steps`` Adam steps."""
    refine_steps: int = 15
    """Adam steps that finish a tracked frame (0: none)."""
    learning_rate: float = 0.005
    """Adam learning rate of the tracked frames' refinement (genome units)."""
    prior: float = 0.003
    """Weight of the motion prior added to the objective in the local search: the
    mean over genes of ``ln(1 + (d / std)^2)``, ``d`` a gene's distance from the
    prediction (a limb the camera does not see stays where the motion model puts
    it, yet may jump where the points show it; 0: off)."""
    velocity: float = 0.5
    """Constant-velocity motion model: the next pose is the last one plus this times
    the last frame's change (0: the last pose)."""
    turn: float = 0.5
    """Largest change of the root's orientation searched in one frame (radians about
    each axis, around the prediction)."""
    move: float = 0.25
    """Largest change of the root's position searched in one frame (metres times the
    tracked scale, around the prediction)."""
    scale_window: float = 1.05
    """A tracked frame's scale stays within this factor of the last one."""
    length_window: float = 1.0
    """A tracked frame's searched link lengths stay within this factor of the last frame's,
    and the motion model predicts them unchanged (1, the default: held at the global fit's
    lengths, since bones keep their length; 0: searched over the skeleton's ranges and
    predicted with the motion's velocity, where a short end link drifted to the end of its
    range: docs/tracking.md, "Lengths held")."""
    keep_scale: bool = True
    """A re-initialisation (the global search after a lost frame, a cost jump or a recheck, once a
    frame was fitted) keeps the subject's scale within ``scale_window`` of the last fitted
    frame's; its lengths are searched again (docs/tracking.md, "Re-initialisations keep the scale")."""
    min_points: int = 50
    """A frame with fewer points than this is lost: the subject is not in view."""
    loss_ratio: float = 1.6
    """A tracked frame whose cost exceeds this times the recent cost (an average over
    the last frames, ``cost_memory``) has lost the subject: the global search runs."""
    cost_memory: float = 0.8
    """Weight of the past in the recent cost (an exponential moving average)."""
    recheck_every: int = 0
    """When this many frames have passed since the global search last ran (or since the
    first frame), a tracked frame also runs the global search, and the cheaper result is
    kept: a fit wrong from the start (which the loss test, comparing a frame with its
    predecessors, cannot see) gets another chance.  Such a frame costs a global fit
    (0: never, the default; docs/tracking.md, "Rechecks")."""
    recheck_margin: float = 0.075
    """A recheck's global fit replaces the tracked one only when it costs less than
    ``1 - recheck_margin`` times as much: a slightly cheaper global fit is as often a
    wrong pose the objective prefers as a better one (docs/tracking.md, "The recheck's margin")."""

    def validate(self) -> "TrackConfig":
        """Raise :class:`ConfigError` naming the first impossible setting; return ``self``."""
        self.fit.validate()
        require_integer("population", self.population, 2)
        require_integer("generations", self.generations, 1)
        require_integer("refine_top", self.refine_top, 0)
        require_integer("refine_steps", self.refine_steps, 0)
        require_integer("sweep_limbs", self.sweep_limbs, 0)
        require_integer("sweep_generations", self.sweep_generations, 1)
        require_integer("sweep_steps", self.sweep_steps, 0)
        require_integer("min_points", self.min_points, 1)
        require_integer("recheck_every", self.recheck_every, 0)
        for name in ("std", "std_final", "learning_rate", "turn", "move"):
            if not require_finite(name, getattr(self, name)) > 0:
                raise ConfigError(f"{name} must be > 0, got {getattr(self, name)!r}")
        if not require_finite("prior", self.prior) >= 0:
            raise ConfigError(f"prior must be >= 0, got {self.prior!r}")
        for name in ("velocity", "branch_reset_rate", "cost_memory"):
            v = require_finite(name, getattr(self, name))
            if not 0.0 <= v <= 1.0 or (name == "cost_memory" and v == 1.0):
                raise ConfigError(f"{name} must lie in [0, 1{')' if name == 'cost_memory' else ']'}, got {v!r}")
        if not require_finite("scale_window", self.scale_window) >= 1.0:
            raise ConfigError(f"scale_window must be >= 1, got {self.scale_window!r}")
        if self.length_window != 0 and not require_finite("length_window", self.length_window) >= 1.0:
            raise ConfigError(f"length_window must be >= 1 (or 0 for the skeleton's ranges), "
                              f"got {self.length_window!r}")
        if not 0.0 <= require_finite("recheck_margin", self.recheck_margin) < 1.0:
            raise ConfigError(f"recheck_margin must lie in [0, 1), got {self.recheck_margin!r}")
        if not require_finite("loss_ratio", self.loss_ratio) > 1.0:
            raise ConfigError(f"loss_ratio must be > 1, got {self.loss_ratio!r}")
        return self

    def for_skeleton(self, skel: Skeleton) -> "TrackConfig":
        """This config with the global search's generations resolved for ``skel``."""
        return dataclasses.replace(self, fit=self.fit.for_skeleton(skel))

    @property
    def refine_count(self) -> int:
        return min(self.refine_top, self.population)

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)
