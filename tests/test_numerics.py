"""NaN safety: the cost and its gradient through decode -> FK -> cost stay finite in degenerate cases."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from jaxpose.io.skeleton_file import load_skeleton
from jaxpose.kinematics import forward_kinematics
from jaxpose.objective import Cloud, ObjectiveConfig, cloud_spread, observe, paper_cost, population_cost
from jaxpose.genome import decode, genome_bounds
from jaxpose.skeleton import LinkSpec, Pose, build_skeleton

from oracles import brute_cost

CFG = ObjectiveConfig(free_space_weight=0.25, block=64)
SETTINGS = dict(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


def f32(x):
    return jnp.asarray(x, jnp.float32)


def _genome_loss(genome, skel, bounds, obs):
    links = forward_kinematics(skel, decode(skel, bounds, genome))
    return population_cost(obs, links.start[None], links.end[None], links.radius[None], CFG)[0]


def _pose_loss(pose, skel, obs):
    links = forward_kinematics(skel, pose)
    return population_cost(obs, links.start[None], links.end[None], links.radius[None], CFG)[0]


genome_value_and_grad = jax.jit(jax.value_and_grad(_genome_loss))
pose_value_and_grad = jax.jit(jax.value_and_grad(_pose_loss))
observe_jit = jax.jit(observe, static_argnames="config")
fk_jit = jax.jit(forward_kinematics)
paper_cost_jit = jax.jit(paper_cost)


def assert_finite(value, grad):
    assert np.isfinite(float(value)), value
    for leaf in jax.tree.leaves(grad):
        assert np.all(np.isfinite(np.asarray(leaf))), grad


N_PAD = 48  # every cloud is padded to this size (weight 0) so that each loss compiles once


def cloud_of(points):
    points = np.asarray(points, np.float32).reshape(-1, 3)
    n = len(points)
    assert n <= N_PAD
    pts = np.concatenate([points, np.zeros((N_PAD - n, 3), np.float32)])
    w = np.concatenate([np.ones(n), np.zeros(N_PAD - n)])
    return observe_jit(Cloud(f32(pts), f32(w)), config=CFG)


@pytest.fixture(scope="module")
def spider():
    skel = load_skeleton("spider")
    rng = np.random.default_rng(0)
    obs = cloud_of(rng.normal([0, 0, 2.0], 0.15, (N_PAD, 3)))
    return skel, genome_bounds(skel, [0, 0, 2.0], 0.5), obs


@pytest.fixture(scope="module")
def degenerate():
    """Zero-length links with and without radius, coincident links, a hinge, a fixed joint."""
    specs = [
        LinkSpec("body", length=0.0, radius=0.0),
        LinkSpec("dot", parent="body", length=0.0, radius=0.05, length_range=(0.0, 0.1)),
        LinkSpec("stick", parent="body", length=0.2, radius=0.0, length_range=(0.0, 0.3)),
        LinkSpec("twin", parent="body", length=0.2, radius=0.0),  # coincides with 'stick'
        LinkSpec("hinge", parent="stick", joint="hinge", axis=(0, 1, 0), length=0.0, radius=0.0),
        LinkSpec("fixed", parent="hinge", joint="fixed", length=0.1, radius=0.02),
    ]
    skel = build_skeleton("degenerate", specs, scale_range=(1e-3, 1e3), require_geometry=False)
    return skel, genome_bounds(skel, [0, 0, 2.0], 0.5)


# --------------------------------------------------------------------------- random genomes and poses


@settings(**SETTINGS)
@given(st.lists(st.floats(-0.5, 1.5), min_size=39, max_size=39))
def test_spider_cost_and_gradient_finite_for_any_genome(spider, genes):
    skel, bounds, obs = spider
    value, grad = genome_value_and_grad(f32(genes), skel, bounds, obs)
    assert_finite(value, grad)
    assert float(value) >= 0.0


@settings(**SETTINGS)
@given(
    angles=st.lists(st.floats(-1e4, 1e4), min_size=24, max_size=24),
    rpy=st.lists(st.floats(-1e4, 1e4), min_size=3, max_size=3),
    log_scale=st.floats(-3, 3),
    lengths=st.lists(st.sampled_from([0.0, 1e-7, 1e-3, 0.1, 10.0]), min_size=8, max_size=8),
)
def test_spider_pose_gradient_finite_for_extreme_poses(spider, angles, rpy, log_scale, lengths):
    """Angles far outside any limit, scales 1e-3 .. 1e3, zero and tiny lengths."""
    skel, _, obs = spider
    scale = 10.0**log_scale
    pose = Pose(f32([0, 0, 2.0]), f32(rpy), f32(scale), f32(angles).reshape(8, 3), f32(lengths))
    value, grad = pose_value_and_grad(pose, skel, obs)
    assert_finite(value, grad)


@settings(**SETTINGS)
@given(
    genes=st.lists(st.sampled_from([0.0, 0.5, 1.0]) | st.floats(0, 1), min_size=22, max_size=22),
    where=st.sampled_from(["start", "end", "mid", "origin"]),
)
def test_degenerate_skeleton_with_points_on_the_axes(degenerate, genes, where):
    """Points exactly at capsule ends and on the axes of zero-radius and zero-length links."""
    skel, bounds = degenerate
    assert skel.num_dof == 22
    g = f32(genes)
    links = fk_jit(skel, decode(skel, bounds, g))
    s, e = np.asarray(links.start), np.asarray(links.end)
    pts = {"start": s, "end": e, "mid": 0.5 * (s + e), "origin": np.asarray(links.origin)}[where]
    pts = np.concatenate([pts, pts, s])  # coincident points too
    value, grad = genome_value_and_grad(g, skel, bounds, cloud_of(pts))
    assert_finite(value, grad)


# --------------------------------------------------------------------------- hand-picked degenerate cases


@pytest.mark.parametrize("scale", [1e-3, 1.0, 1e3])
def test_scaled_model_fitting_its_own_points(degenerate, scale):
    """Huge and tiny scale, the cloud on the model's own axes (d ~ 0)."""
    skel, _ = degenerate
    pose = Pose(f32([0, 0, 2.0 * scale]), f32([0.3, -0.2, 0.1]), f32(scale), jnp.zeros((6, 3)), skel.length)
    links = fk_jit(skel, pose)
    t = np.linspace(0, 1, 5)[:, None, None]
    pts = (np.asarray(links.start) + t * (np.asarray(links.end) - np.asarray(links.start))).reshape(-1, 3)
    obs = cloud_of(pts)
    value, grad = pose_value_and_grad(pose, skel, obs)
    assert_finite(value, grad)
    # and the value agrees with the brute force at this scale
    got = float(paper_cost_jit(pts, np.ones(len(pts)), links.start, links.end, links.radius))
    want = brute_cost(pts, np.ones(len(pts)), np.asarray(links.start), np.asarray(links.end), np.asarray(links.radius))
    assert got == pytest.approx(want, rel=1e-4, abs=1e-5)


def test_cloud_of_identical_points(spider):
    """sigma = 0 in exact arithmetic: the cost must stay finite and differentiable."""
    skel, bounds, _ = spider
    obs = cloud_of(np.tile([[0.01, -0.02, 2.0]], (N_PAD, 1)))
    assert np.isfinite(float(obs.sigma)) and float(obs.sigma) > 0
    for g in (0.0, 0.5, 1.0):
        value, grad = genome_value_and_grad(jnp.full(39, g, jnp.float32), skel, bounds, obs)
        assert_finite(value, grad)
    # a single point, and a single point sitting on a capsule end
    links = fk_jit(skel, decode(skel, bounds, jnp.full(39, 0.5, jnp.float32)))
    for p in ([[0.0, 0.0, 2.0]], np.asarray(links.end[3:4])):
        value, grad = genome_value_and_grad(jnp.full(39, 0.5, jnp.float32), skel, bounds, cloud_of(p))
        assert_finite(value, grad)


def test_all_padding_cloud_is_finite(spider):
    skel, bounds, _ = spider
    cloud = Cloud(jnp.zeros((N_PAD, 3)), jnp.zeros(N_PAD))
    assert np.isfinite(float(cloud_spread(cloud)))
    obs = observe_jit(cloud, config=CFG)
    value, grad = genome_value_and_grad(jnp.full(39, 0.5, jnp.float32), skel, bounds, obs)
    assert_finite(value, grad)


def test_cloud_gradient_finite_at_degenerate_points():
    """The data term is also differentiable w.r.t. the points (zero-length segment, point on it)."""

    def loss(points):
        start = f32([[0.0, 0.0, 2.0], [0.0, 0.0, 2.0]])
        end = f32([[0.0, 0.0, 2.0], [0.2, 0.0, 2.0]])
        return paper_cost(points, jnp.ones(points.shape[0]), start, end, f32([0.0, 0.0]))

    vg = jax.jit(jax.value_and_grad(loss))
    for pts in ([[0.0, 0.0, 2.0]] * 3, [[0.1, 0.0, 2.0], [0.0, 0.0, 2.0], [0.2, 0.0, 2.0]]):
        value, grad = vg(f32(pts))
        assert_finite(value, grad)
