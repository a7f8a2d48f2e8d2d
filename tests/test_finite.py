"""Finiteness properties: any genome of any shipped skeleton gives finite kinematics,
and a fit on a degenerate cloud gives a finite result.

Genomes are drawn in ``[0, 1]^D`` with the corners 0 and 1 over-represented, plus a
few values outside (``decode`` clips).  Besides finiteness, every pose is checked
against NumPy formulas written from ``jaxpose/skeleton.py``'s docstring: decoded
values are ``lo + clip(g) (hi - lo)``; rotations are proper; capsule ends are
``origin + R (s seg_start)`` and ``+ s length R seg_dir``; a child's origin is
``origin_p + R_p (s (offset + attach (seg_start_p + length_p seg_dir_p)))``.
"""

from __future__ import annotations

from functools import lru_cache

import jax
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import jaxpose as jp
from oracles import rpy
from jaxpose.genome import genome_layout

SKELETONS = jp.shipped_skeletons()
PROPS = settings(max_examples=25, deadline=None, derandomize=True,
                 suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


def test_skeletons_are_shipped():
    assert {"spider", "humanoid", "arm7", "snake"} <= set(SKELETONS)


@lru_cache(maxsize=None)
def model(name):
    skel = jp.load_skeleton(name)

    @jax.jit
    def run(lo, hi, genome):
        pose = jp.decode(skel, jp.genome.Bounds(lo, hi), genome)
        return pose, jp.forward_kinematics(skel, pose)

    return skel, run


def flat_pose(pose):
    """The flat parameter vector ``[root_t, root_rpy, scale, angles (L*3), lengths]`` (GenomeLayout)."""
    return np.concatenate([np.ravel(pose.root_t), np.ravel(pose.root_rpy), np.ravel(pose.scale),
                           np.ravel(pose.angles), np.ravel(pose.lengths)]).astype(np.float64)


def check_pose(name, genome, centre=(0.0, 0.0, 2.0), extent=1.0):
    skel, run = model(name)
    bounds = jp.genome_bounds(skel, np.asarray(centre, np.float32), np.float32(extent))
    lo, hi = np.asarray(bounds.lo, np.float64), np.asarray(bounds.hi, np.float64)
    g = np.asarray(genome, np.float32)
    pose, links = run(bounds.lo, bounds.hi, g)

    for leaf in jax.tree_util.tree_leaves((pose, links)):
        assert np.all(np.isfinite(np.asarray(leaf))), (name, genome)

    # decode: every gene maps linearly onto its range
    target = np.asarray(genome_layout(skel).target)
    expect = lo + np.clip(g.astype(np.float64), 0, 1) * (hi - lo)
    np.testing.assert_allclose(flat_pose(pose)[target], expect, rtol=1e-5, atol=1e-5)

    R = np.asarray(links.R_world_link, np.float64)
    origin = np.asarray(links.origin, np.float64)
    L = skel.num_links
    assert R.shape == (L, 3, 3) and origin.shape == np.asarray(links.start).shape == np.asarray(links.end).shape == (L, 3)
    np.testing.assert_allclose(R @ np.swapaxes(R, 1, 2), np.broadcast_to(np.eye(3), (L, 3, 3)), atol=1e-4)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-4)

    s = float(pose.scale)
    lengths = np.asarray(pose.lengths, np.float64)
    seg_start = np.asarray(skel.seg_start, np.float64)
    seg_dir = np.asarray(skel.seg_dir, np.float64)
    offset = np.asarray(skel.offset, np.float64)
    attach = np.asarray(skel.attach, np.float64)
    start = origin + np.einsum("lij,lj->li", R, s * seg_start)
    end = start + np.einsum("lij,lj->li", R, s * lengths[:, None] * seg_dir)
    tol = 1e-4 * max(1.0, np.abs(origin).max())
    np.testing.assert_allclose(np.asarray(links.start), start, atol=tol)
    np.testing.assert_allclose(np.asarray(links.end), end, atol=tol)
    np.testing.assert_allclose(np.asarray(links.radius), s * np.asarray(skel.radius), rtol=1e-5, atol=1e-7)
    R_root = rpy(*np.asarray(pose.root_rpy, np.float64))
    t_root = np.asarray(pose.root_t, np.float64)
    for i, p in enumerate(skel.parents):
        if p < 0:
            want = t_root + R_root @ (s * offset[i])
        else:
            anchor = offset[i] + attach[i] * (seg_start[p] + lengths[p] * seg_dir[p])
            want = origin[p] + R[p] @ (s * anchor)
        np.testing.assert_allclose(origin[i], want, atol=tol, err_msg=f"{name}: origin of {skel.link_names[i]}")


gene = st.one_of(st.sampled_from([0.0, 1.0]), st.floats(0.0, 1.0, width=32), st.floats(-2.0, 3.0, width=32))


@pytest.mark.parametrize("name", SKELETONS)
@PROPS
@given(data=st.data())
def test_random_poses_are_finite(name, data):
    skel, _ = model(name)
    D = genome_layout(skel).size
    genome = data.draw(st.lists(gene, min_size=D, max_size=D), label="genome")
    centre = data.draw(st.tuples(*[st.floats(-3.0, 3.0)] * 3), label="centre")
    extent = data.draw(st.floats(1e-3, 5.0), label="extent")
    check_pose(name, genome, centre, extent)


@pytest.mark.parametrize("name", SKELETONS)
@pytest.mark.parametrize("corner", ["zeros", "ones", "alternating", "alternating_other"])
def test_corner_poses_are_finite(name, corner):
    skel, _ = model(name)
    D = genome_layout(skel).size
    genome = {
        "zeros": np.zeros(D), "ones": np.ones(D),
        "alternating": np.arange(D) % 2, "alternating_other": 1 - np.arange(D) % 2,
    }[corner]
    check_pose(name, genome)


# --------------------------------------------------------------------------- degenerate clouds

TINY = jp.FitConfig(population=8, generations=3, islands=1, memetic_steps=0, final_refine_steps=2, turns=0)
N, REAL = 64, 48  # every cloud has the same array size (one compilation) and 16 padding points


def _cloud(points):
    cloud = jp.points_to_cloud(np.asarray(points, np.float32), max_points=N)
    assert int(np.asarray(cloud.weights).sum()) == REAL
    return cloud


DEGENERATE = {
    "one_point": np.tile([0.1, -0.2, 1.5], (REAL, 1)),
    "a_line": np.linspace([0.0, 0.0, 1.0], [0.4, 0.2, 2.0], REAL),
    "a_short_line": np.linspace([0.0, 0.0, 1.0], [0.0, 0.0, 1.0 + 1e-6], REAL),
}


@pytest.mark.parametrize("case", sorted(DEGENERATE))
def test_fit_on_a_degenerate_cloud_is_finite(case):
    skel = jp.load_skeleton("spider")
    result = jp.fit_cloud(_cloud(DEGENERATE[case]), skel, seed=0, config=TINY)
    assert isinstance(result, jp.FitResult)
    for path, leaf in jax.tree_util.tree_flatten_with_path(result)[0]:
        assert np.all(np.isfinite(np.asarray(leaf))), (case, jax.tree_util.keystr(path))
    assert float(result.cost) >= 0 and np.asarray(result.history).shape == (TINY.generations,)
    g = np.asarray(result.genome)
    assert g.shape == (genome_layout(skel).size,) and np.all((g >= 0) & (g <= 1))
    assert np.asarray(result.links.end).shape == (skel.num_links, 3)
