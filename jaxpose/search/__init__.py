"""Search: the branch-swap GA, baselines, optax refinement and ``fit``."""

from .baselines import BoundedHillClimbing, evosax_strategy
from .fit import FitConfig, Fitter, FitResult, auto_generations, fit, fit_cloud, initial_population
from .ga import BranchSwapGA, branch_swap, mutate, subtree_masks
from .refine import refine

__all__ = [
    "BoundedHillClimbing", "BranchSwapGA", "FitConfig", "FitResult", "Fitter", "auto_generations", "branch_swap",
    "evosax_strategy",
    "fit", "fit_cloud", "initial_population", "mutate", "refine", "subtree_masks",
]
