"""Baselines in the same ask/tell framework: hill climbing and any evosax strategy."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from evosax.algorithms import algorithms as EVOSAX_ALGORITHMS
from evosax.algorithms.distribution_based.hill_climbing import HillClimbing

from ..errors import ConfigError


class BoundedHillClimbing(HillClimbing):
    """evosax's Gaussian hill climbing with samples clipped to the genome box ``[0, 1]``.

    Each generation samples ``population_size`` neighbours of the best solution so
    far and moves there when one is better (a parallel, first-improvement climber).
    """

    def _ask(self, key: jax.Array, state, params):
        population, state = super()._ask(key, state, params)
        return jnp.clip(population, 0.0, 1.0), state


def evosax_strategy(name: str):
    """An evosax algorithm class by name, case-insensitively (``cma_es`` -> ``CMA_ES``)."""
    table = {k.lower(): v for k, v in EVOSAX_ALGORITHMS.items()}
    cls = table.get(name.lower())
    if cls is None:
        known = ", ".join(sorted(EVOSAX_ALGORITHMS))
        raise ConfigError(f"unknown algorithm {name!r}: use 'ga', 'hc' or an evosax strategy ({known})")
    return cls
