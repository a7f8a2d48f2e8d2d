"""What the search's tests share: skeletons, synthetic clouds, tiny configs, oracles.

Fit tests share a handful of tiny configurations (population 8-16, 4 generations,
a cloud of 128 points sampled on the spider's capsules in a known pose); every
configuration is compiled once per session (``Fitter`` caches its compiled
programs by static config and signature) and :func:`run` caches its results, so
most tests only reuse them.  Every config sets ``islands`` explicitly: the default
may change.

Expected evaluation counts (:func:`expected_counts`) are written from the
documented budget (``FitConfig`` and ``jaxpose.search.loop`` docstrings), not from
the code:

* each generation (the first evaluates the initial population): ``population``;
* memetic step (GA only, on when ``memetic_top`` and ``memetic_steps`` are both
  positive), at the end of every epoch, a shorter last one included:
  ``m * memetic_steps`` gradients, ``m = min(memetic_top, population)``;
* final refinement: ``min(final_refine_top, population)`` candidates for the GA,
  the single best for the other algorithms, each ``final_refine_steps`` gradients;
* coarse to fine: the population and the best so far rescored at the switch;
* everything times ``islands``.

Compilations are counted (:func:`count_compiles`) with a ``jax.monitoring``
listener on XLA's backend-compile event: it fires once per executable built,
cached or not, so the counts hold whatever other tests compiled before.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np

import jaxpose
from jaxpose import Cloud, ObjectiveConfig, forward_kinematics, observe, population_cost, rest_pose
from jaxpose.camera import points_to_cloud
from jaxpose.search import FitConfig, fit_cloud
from jaxpose.search.coarse import coarse_switch
from jaxpose.skeleton import LinkSpec, build_skeleton

SHIPPED = ("spider", "humanoid", "arm7", "snake")
N_POINTS = 128
OBJ = ObjectiveConfig(free_space_grid=16, block=64)

# memetic_top above the population: clamped to it
GA = FitConfig(
    algorithm="ga", population=16, generations=4, epoch=2, memetic_top=20, memetic_steps=2,
    final_refine_top=20, final_refine_steps=3, islands=1, objective=OBJ, staged_alternatives=(), turns=0, limb_sweep=0,
    pivot_sweep=0,
)
# no refinement: the plain search budget, population * generations
GA_PLAIN = dataclasses.replace(GA, epoch=4, memetic_steps=0, final_refine_steps=0)
ISLANDS = dataclasses.replace(GA, population=8, memetic_top=3, final_refine_steps=0, islands=2)
# a large step so that the first generation's neighbours are all worse than the start
HC = FitConfig(
    algorithm="hc", population=16, generations=4, epoch=4, std_init=0.6, std_final=0.4, memetic_steps=0,
    final_refine_top=3, final_refine_steps=1, islands=1, objective=OBJ, staged_alternatives=(), turns=0, limb_sweep=0,
    pivot_sweep=0,
)
CMA = dataclasses.replace(GA_PLAIN, algorithm="cma_es")
# coarse to fine: one block of 64 points of two until generation 2
COARSE = dataclasses.replace(ISLANDS, coarse_points=40)
# a portfolio: the staged search and one without staging (FitConfig's default)
PORTFOLIO = dataclasses.replace(ISLANDS, staged=0.5, staged_alternatives=(0.0,))
ALL = [GA, GA_PLAIN, HC, ISLANDS, CMA, COARSE, PORTFOLIO]
IDS = ["ga", "ga-plain", "hc", "ga-islands2", "cma_es", "ga-coarse", "portfolio"]


@functools.cache
def skeleton(name="spider"):
    return jaxpose.load_skeleton(name)


def branchy_skeleton():
    """A tree listed children-first, with a fixed joint and fixed lengths (links without genes)."""
    links = [
        LinkSpec("d", parent="c", joint="ball", length=0.1),
        LinkSpec("e", parent="b", joint="hinge", length=0.1, length_range=(0.05, 0.2)),
        LinkSpec("a", joint="ball", length=0.2, length_range=(0.1, 0.3)),
        LinkSpec("c", parent="a", joint="fixed", length=0.1),  # no genes at all
        LinkSpec("b", parent="a", joint="hinge", length=0.1),
        LinkSpec("f", parent="d", joint="fixed", length=0.1, length_range=(0.05, 0.1)),
        LinkSpec("g", joint="hinge", length=0.1),
    ]
    return build_skeleton("branchy", links)


def descendants(skel, k):
    """Link ``k`` and every link below it, from the parent list alone (an oracle for subtrees)."""
    out, todo = set(), [k]
    while todo:
        i = todo.pop()
        out.add(i)
        todo += [j for j, p in enumerate(skel.parents) if p == i]
    return out


# --------------------------------------------------------------------------- synthetic data


def true_pose(skel, seed=0):
    rng = np.random.default_rng(seed)
    lo, hi = np.asarray(skel.angle_lo), np.asarray(skel.angle_hi)
    rest = rest_pose(skel, root_t=(0.03, -0.02, 1.2), root_rpy=(0.4, -0.3, 0.6), scale=1.0)
    angles = lo + (0.2 + 0.6 * rng.uniform(size=lo.shape)) * (hi - lo)  # well inside the limits
    return rest._replace(angles=jnp.asarray(angles, jnp.float32))


def capsule_surface_cloud(start, end, radius, n, seed):
    """Noiseless points uniformly along every capsule's axis, on its cylindrical wall (NumPy)."""
    rng = np.random.default_rng(seed)
    s, e, r = (np.asarray(a, np.float64) for a in (start, end, radius))
    li = rng.integers(0, len(s), n)
    ax = e[li] - s[li]
    u = rng.normal(size=(n, 3))
    u -= (u * ax).sum(1, keepdims=True) / (ax * ax).sum(1, keepdims=True) * ax
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    pts = s[li] + rng.uniform(size=(n, 1)) * ax + r[li][:, None] * u
    return Cloud(jnp.asarray(pts, jnp.float32), jnp.ones(n, jnp.float32))


@functools.cache
def spider_cloud(seed=0):
    skel = skeleton()
    links = forward_kinematics(skel, true_pose(skel, seed))
    return capsule_surface_cloud(links.start, links.end, links.radius, N_POINTS, seed)


@functools.cache
def run(config: FitConfig, seed: int = 0, cloud_seed: int = 0):
    return fit_cloud(spider_cloud(cloud_seed), skeleton(), seed, config)


def expected_counts(config: FitConfig):
    """(objective, gradient) evaluations from the documented budget (module docstring)."""
    P, G = config.population, config.generations
    obj, grad = G * P, 0
    if config.algorithm == "ga" and min(config.memetic_top, config.memetic_steps) > 0:
        refinements = -(-G // config.epoch)  # one per full epoch and one after a shorter last epoch
        grad += refinements * min(config.memetic_top, P) * config.memetic_steps
    if config.final_refine_steps > 0 and config.final_refine_top > 0:
        m = min(config.final_refine_top, P) if config.algorithm == "ga" else 1
        grad += m * config.final_refine_steps
    if coarse_switch(config, N_POINTS) is not None:  # coarse to fine: population and best rescored
        obj += P + 1
    obj, grad = obj * config.islands, grad * config.islands
    if config.limb_sweep:  # once per search (not per island): every subtree's GA, then Adam on its best 2
        masks = sum(1 for k in range(skeleton().num_links)
                    if any(".q" in n for n in jaxpose.genome_layout(skeleton()).names
                           if n.rsplit(".", 1)[0] in {skeleton().link_names[i] for i in descendants(skeleton(), k)}))
        obj, grad = obj + masks * P * config.limb_sweep, grad + masks * min(2, P) * 30
    if config.pivot_sweep:  # every link with two links or more below it and joint angles elsewhere
        skel, names = skeleton(), jaxpose.genome_layout(skeleton()).names
        pivots = sum(1 for k in range(skel.num_links) if len(descendants(skel, k)) >= 2 and any(
            ".q" in n for n in names if n.rsplit(".", 1)[0] not in {skel.link_names[i] for i in descendants(skel, k)}))
        obj, grad = obj + pivots * P * config.pivot_sweep, grad + pivots * min(2, P) * 30
    n = config.searches  # a portfolio counts every search's evaluations
    return obj * n, grad * n


@functools.partial(jax.jit, static_argnames="config")
def _cost(cloud, start, end, radius, config):
    return population_cost(observe(cloud, config), start[None], end[None], radius[None], config)[0]


def links_cost(cloud, links, config=OBJ):
    """The objective of one posed model, straight from ``jaxpose.objective``."""
    return float(_cost(cloud, links.start, links.end, links.radius, config))


# --------------------------------------------------------------------------- compilations

BACKEND_COMPILE_EVENT = "/jax/core/compile/backend_compile_duration"


@contextlib.contextmanager
def count_compiles():
    """Collect the names of the functions XLA compiles inside the block."""
    names: list[str] = []

    def listener(event, duration, **kwargs):
        if event == BACKEND_COMPILE_EVENT:
            names.append(str(kwargs.get("fun_name", "?")))

    jax.monitoring.register_event_duration_secs_listener(listener)
    try:
        yield names
    finally:
        jax.monitoring.unregister_event_duration_listener(listener)


# --------------------------------------------------------------------------- a probe for compile counts

PROBE_POINTS = 96  # the probe clouds' padded size


def probe_skeleton():
    """A tiny two-link skeleton whose name no other test uses: a short compile, and
    the first fit of a config really compiles."""
    links = [
        LinkSpec("recompile_a", joint="ball", limits=[[-30, 30]] * 3, length=0.2, radius=0.02),
        LinkSpec("recompile_b", parent="recompile_a", joint="hinge", limits=[[-60, 60]], length=0.15,
                 length_range=(0.1, 0.2), radius=0.015),
    ]
    return build_skeleton("recompile_probe", links)


def probe_cloud(seed: int, n_valid: int):
    """A noisy bent stick ~1.5 m in front of the camera, padded to PROBE_POINTS."""
    rng = np.random.default_rng(seed)
    t = rng.uniform(0, 1, n_valid)
    pts = np.stack([0.3 * t - 0.1, 0.1 * np.sin(3 * t), 1.5 + 0.05 * t], -1)
    pts = pts + 0.01 * rng.standard_normal(pts.shape)
    c = points_to_cloud(pts, PROBE_POINTS, seed)
    assert c.points.shape == (PROBE_POINTS, 3)
    return c
