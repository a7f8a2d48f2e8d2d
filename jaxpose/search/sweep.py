"""Limb sweeps: after the search, every limb searched again with the rest of the body held.

The islands settle the trunk early; a limb then caught in a wrong basin (an arm
folded behind the back while the points put it in front) stays there, because by
then mutation steps are small and Adam only descends.  A sweep takes the search's
best and, limb after limb down the tree (every link's subtree, trunk side first),
runs a small GA over that subtree's joint angles alone, from angles drawn
uniformly within their limits and the current ones, with every other gene held;
Adam then polishes its best few on every gene (unless the final refinement is
off), and the limb's new place is kept when it lowers the cost.  A systematic
search of each limb given the rest, where the GA's branch resets are rare random
jumps (docs/search.md, "Limb sweep").

A pivot sweep is the converse, for a trunk placed wrong beside a limb placed right
(the legs on their points, the torso turned away): for every link, its subtree is
held where it is in the world and the rest of the body is searched again around it
(every other joint angle, and the link's own), the root pose following from the
held link's frame, as if the tree were rooted there (docs/search.md, "Pivot sweep").
"""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from ..genome import Bounds, decode, genome_layout, root_rpy_values
from ..geometry import matrix_to_rpy, rpy_matrix
from ..kinematics import forward_kinematics
from ..skeleton import Skeleton
from .config import FitConfig
from .ga import BranchSwapGA, subtree_masks
from .genes import tie_lengths
from .memetic import hop_masks, keep_better
from .refine import refine

SWEEP_REFINE_TOP = 2  # the sweep's best individuals that Adam polishes, per limb
SWEEP_REFINE_STEPS = 30  # their Adam steps


def sweep_masks(skel: Skeleton) -> np.ndarray:
    """``(K, D)`` boolean: the joint-angle genes of every link's subtree that has any, in
    the skeleton's tree order (a parent's subtree before its children's)."""
    masks = hop_masks(skel)[:-1]  # the last row is the root's orientation
    return masks[masks.any(axis=1)]


def pivot_links(skel: Skeleton) -> np.ndarray:
    """The links a pivot sweep holds: every link whose subtree has two bodies or more
    (one capsule's frame is not held by its points: its spin about its axis is free)
    and whose complement has joint angles.  Of a robot file's body with several joints
    (a chain of links ``body/joint`` ending in ``body``, :mod:`jaxpose.io.mjcf`) only
    ``body`` is a pivot: its chain's other joints are then searched."""
    masks = _pivot_masks(skel)
    names, body = skel.link_names, skel.bodies
    helper = ["/" in n and n.rsplit("/", 1)[0] in names for n in names]
    keep = [k for k in range(skel.num_links)
            if not helper[k] and (masks[k] & ~_own_mask(skel, k)).any()
            and len({body[j] for j in skel.subtree(k) if not helper[j]}) >= 2]
    return np.asarray(keep, np.int32)


def _own_mask(skel: Skeleton, k: int) -> np.ndarray:
    return genome_layout(skel).gene_mask([k])


def _pivot_masks(skel: Skeleton) -> np.ndarray:
    """``(L, D)`` boolean: the joint-angle genes outside link ``k``'s subtree, and ``k``'s own."""
    layout = genome_layout(skel)
    angle = np.array([".q" in n for n in layout.names])
    own = np.stack([_own_mask(skel, k) for k in range(skel.num_links)])
    return angle[None] & (~subtree_masks(skel) | own)


def sweep_counts(skel: Skeleton, config: FitConfig) -> tuple[int, int]:
    """``(objective evaluations, gradient evaluations)`` of one sweep (pivots and limbs)."""
    top = min(SWEEP_REFINE_TOP, config.population)
    steps = SWEEP_REFINE_STEPS if config.final_refine_on else 0  # no refinement at all: no Adam here either
    K = len(sweep_masks(skel)) if config.limb_sweep else 0
    Kp = len(pivot_links(skel)) if config.pivot_sweep else 0
    P = config.population
    return K * P * config.limb_sweep + Kp * P * config.pivot_sweep, (K + Kp) * top * steps


def pivot_root(skel: Skeleton, bounds: Bounds, genomes, k, R_held, origin_held):
    """``genomes (P, D)`` with the root pose that puts link ``k``'s frame at ``R_held,
    origin_held`` (world), every joint angle kept: the body turned and moved about ``k``.
    Root genes clip to their bounds (then ``k`` is only as near as they allow)."""
    poses = jax.vmap(partial(decode, skel, bounds))(genomes)
    links = jax.vmap(partial(forward_kinematics, skel))(poses)
    R_root = rpy_matrix(poses.root_rpy)
    turn = R_held[None] @ jnp.swapaxes(links.R_world_link[:, k], -1, -2)  # (P, 3, 3): world turn taking k home
    R_new = turn @ R_root
    t_new = origin_held[None] - jnp.einsum("pij,pj->pi", turn, links.origin[:, k] - poses.root_t)
    root = jnp.concatenate([t_new, root_rpy_values(bounds, matrix_to_rpy(R_new), inverse=True)], -1)
    lo, hi = bounds.lo[:6], bounds.hi[:6]
    return genomes.at[:, :6].set(jnp.clip((root - lo) / jnp.maximum(hi - lo, 1e-9), 0.0, 1.0))


def limb_sweep(skel: Skeleton, config: FitConfig, cost, genome, genome_cost, key, learning_rate,
               bounds: Bounds | None = None):
    """Sweep ``genome (D,)`` (its cost ``genome_cost``) under ``cost(genomes (P, D)) -> (P,)``:
    the pivots first (``config.pivot_sweep`` generations each; they need the genes'
    ``bounds``), then the limbs (``config.limb_sweep``), ``config.population`` individuals.

    Returns ``(genome, cost)``: never worse than the input."""
    if config.tie_lengths:
        raw = cost
        cost = lambda g: raw(tie_lengths(skel, g))  # noqa: E731
    k_pivot, k_limb = jax.random.split(key)
    g, f = genome, genome_cost
    pivots = pivot_links(skel)
    if config.pivot_sweep and len(pivots):
        if bounds is None:
            raise ValueError("a pivot sweep needs the genes' bounds")
        masks = jnp.asarray(_pivot_masks(skel)[pivots])

        def around(pop, g, mask, k):  # the held link's frame, from the sweep's current best
            links = forward_kinematics(skel, decode(skel, bounds, g))
            pop = jnp.where(mask, pop, g[None])
            return pivot_root(skel, bounds, pop, k, links.R_world_link[k], links.origin[k])

        g, f = sweep_rows(skel, config, cost, g, f, k_pivot, learning_rate, masks, jnp.asarray(pivots), around,
                          config.pivot_sweep)
    if config.limb_sweep:
        masks = jnp.asarray(sweep_masks(skel))
        rows = jnp.zeros(masks.shape[0], jnp.int32)  # (unused by `hold`)
        g, f = sweep_rows(skel, config, cost, g, f, k_limb, learning_rate, masks, rows, hold, config.limb_sweep)
    return g, f


def hold(pop, genome, mask, link):
    """A limb sweep's ``prepare``: every gene outside ``mask`` held at ``genome``'s."""
    return jnp.where(mask, pop, genome[None])


def sweep_rows(skel: Skeleton, config: FitConfig, cost, genome, genome_cost, key, learning_rate, masks, links,
               prepare, G: int, steps: int = SWEEP_REFINE_STEPS):
    """One small GA per row of ``masks (K, D)`` (``links (K,)``: a number each row passes to
    ``prepare(pop, best, mask, link) -> pop``, which sets the genes the row holds), one row
    after another from the best so far; Adam polishes each row's best few (``steps`` steps,
    none when 0 or when ``config``'s final refinement is off).  Returns ``(genome, cost)``."""
    P = config.population
    D = genome.shape[-1]
    decay = (config.std_final / config.std_init) ** (1.0 / max(G, 1))
    schedule = lambda n: config.std_init * decay ** n  # noqa: E731
    # the limb's genes only: crossover and mutation pick among them, other genes are held
    algo = BranchSwapGA(P, jnp.zeros(D, jnp.float32), subtree_masks(skel), std_schedule=schedule,
                        elite_ratio=config.elite_ratio)
    # every child moves every gene of the limb (mutations elsewhere would be undone by the mask)
    params = algo.default_params.replace(mutation_rate=1.0, branch_mutation_rate=0.0, branch_reset_rate=0.1)
    top = min(SWEEP_REFINE_TOP, P)

    def one_limb(carry, inputs):
        g, f = carry
        mask, link, k = inputs
        k_pop, k_init, k_run = jax.random.split(k, 3)
        fresh = jax.random.uniform(k_pop, (P - 1, D), g.dtype)
        pop0 = jnp.concatenate([g[None], prepare(fresh, g, mask, link)])
        state = algo.init(k_init, pop0, cost(pop0), params)

        def generation(state, kg):
            k_ask, k_tell = jax.random.split(kg)
            pop, asked = algo.ask(k_ask, state, params)
            pop = prepare(pop, g, mask, link)
            state, _ = algo.tell(k_tell, pop, cost(pop), asked, params)
            return state, None

        state, _ = jax.lax.scan(generation, state, jax.random.split(k_run, G - 1)) if G > 1 else (state, None)
        best_g, best_f = state.best_solution, state.best_fitness
        if config.final_refine_on and steps > 0:
            order = jnp.argsort(state.fitness)[:top]
            rg, rf = refine(cost, state.population[order], jnp.int32(steps), learning_rate)
            best_g, best_f = keep_better(rg, rf, best_g, best_f)
        return keep_better(best_g[None], best_f[None], g, f), None

    keys = jax.random.split(key, masks.shape[0])
    (g, f), _ = jax.lax.scan(one_limb, (genome, genome_cost), (masks, links, keys))
    return g, f
