"""Search: the branch-swap GA, baselines, optax refinement, and the fit that runs them.

Modules, one idea each: ``config`` (settings, static and traced), ``init`` (bounds
and initial population), ``genes`` (staged search, tied lengths), ``islands``,
``coarse`` (coarse-to-fine scoring), ``memetic`` (refinement inside the search),
``loop`` (the pure search and :func:`fit`), ``compiled`` (:class:`Fitter`, the
compiled programs and their cache), ``cost`` (the cost of poses and genomes), ``sweep``
(pivot and limb sweeps), ``hypotheses``; ``ga``, ``baselines``, ``refine``.
"""

from .baselines import BoundedHillClimbing, evosax_strategy
from .compiled import Fitter, fit_cloud
from .config import FitConfig, FitParams, auto_generations
from .ga import BranchSwapGA, branch_swap, mutate, subtree_masks
from .init import initial_population
from .loop import best_of, evaluation_counts, fit
from .refine import refine
from .state import FitResult, SearchState

__all__ = [
    "BoundedHillClimbing", "BranchSwapGA", "FitConfig", "FitParams", "FitResult", "Fitter", "SearchState",
    "auto_generations", "best_of", "branch_swap", "evaluation_counts", "evosax_strategy", "fit", "fit_cloud",
    "initial_population", "mutate", "refine", "subtree_masks",
]
