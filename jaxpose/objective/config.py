"""The cost's settings."""

from __future__ import annotations

from dataclasses import dataclass

from ..errors import ConfigError, require_finite, require_integer


@dataclass(frozen=True)
class ObjectiveConfig:
    """Static settings of the cost (hashable, so usable as a jit static argument)."""

    sigma: float | None = None  # None: cloud_spread(cloud)
    sigma_factor: float = 0.25  # multiplies the spread (1: the paper's sigma)
    free_space_weight: float = 1.0
    free_space_samples: int = 6
    free_space_grid: int = 40
    max_range: float | None = None  # metres the sensor measures at most (None: no limit); see free_space_cost
    collision_weight: float = 0.1
    collision_margin: float = 0.8  # clearance of two capsules' axes, a fraction of r_i + r_j
    block: int = 256  # points per streamed block in the kernel

    def validate(self) -> "ObjectiveConfig":
        """Raise :class:`~jaxpose.errors.ConfigError` naming the first impossible setting; return ``self``."""
        def number(name):
            return require_finite(f"objective.{name}", getattr(self, name))

        if self.sigma is not None and not number("sigma") > 0:
            raise ConfigError(f"objective.sigma must be > 0 metres (or None: from the cloud), got {self.sigma}")
        if self.max_range is not None and not number("max_range") > 0:
            raise ConfigError(f"objective.max_range must be > 0 metres (or left unset: no limit), got {self.max_range}")
        if not number("sigma_factor") > 0:
            raise ConfigError(f"objective.sigma_factor must be > 0, got {self.sigma_factor}")
        for name in ("free_space_weight", "collision_weight"):
            if not number(name) >= 0:
                raise ConfigError(f"objective.{name} must be >= 0, got {getattr(self, name)}")
        if not 0 < number("collision_margin") <= 2:
            raise ConfigError(f"objective.collision_margin must lie in (0, 2], got {self.collision_margin}")
        for name, lo in (("free_space_samples", 1), ("free_space_grid", 2), ("block", 1)):
            require_integer(f"objective.{name}", getattr(self, name), lo)
        return self
