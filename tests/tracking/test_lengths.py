"""Link lengths in tracked frames (``TrackConfig.length_window``): bones keep their length
from frame to frame.  Oracles: the window's bounds recomputed in NumPy from the skeleton's
ranges; the lengths a tracker started from a known pose returns, frame after frame."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_tracking import CFG, surface_cloud, true_pose

import jaxpose as jp
from jaxpose.tracking import TrackConfig, Tracker
from jaxpose.tracking.local import local_bounds


@pytest.fixture(scope="module")
def skel():
    return jp.load_skeleton("humanoid")  # lengths searched on every limb


def length_rows(skel):
    layout = jp.genome_layout(skel)
    return [(k, layout.link_of_gene[k]) for k, n in enumerate(layout.names) if n.endswith(".length")]


@pytest.mark.parametrize("window", [1.0, 1.1])
def test_the_length_genes_span_the_window_within_the_skeletons_range(skel, window):
    pred = true_pose(skel, 0)
    lengths = np.asarray(skel.length_lo) + np.linspace(0.0, 1.0, skel.num_links) * (
        np.asarray(skel.length_hi) - np.asarray(skel.length_lo))  # the range's ends included
    pred = pred._replace(lengths=jnp.asarray(lengths, jnp.float32))
    b = local_bounds(skel, dataclasses.replace(CFG, length_window=window), pred)
    free = local_bounds(skel, dataclasses.replace(CFG, length_window=0.0), pred)
    rows = length_rows(skel)
    assert rows
    for k, link in rows:
        lo = max(float(skel.length_lo[link]), lengths[link] / window)
        hi = max(min(float(skel.length_hi[link]), lengths[link] * window), lo)
        np.testing.assert_allclose([float(b.lo[k]), float(b.hi[k])], [lo, hi], rtol=1e-6)
        np.testing.assert_allclose([float(free.lo[k]), float(free.hi[k])],
                                   [float(skel.length_lo[link]), float(skel.length_hi[link])])
    others = np.setdiff1d(np.arange(b.lo.shape[0]), [k for k, _ in rows])
    np.testing.assert_array_equal(np.asarray(b.lo)[others], np.asarray(free.lo)[others])
    np.testing.assert_array_equal(np.asarray(b.hi)[others], np.asarray(free.hi)[others])


def track_lengths(skel, config, init, frames: int = 4):
    tr = Tracker(skel, config, key=jax.random.key(1), init=init)
    out = []
    for t in range(frames):
        r = tr.update(surface_cloud(skel, true_pose(skel, t), t))
        assert tr.mode == "tracked"
        out.append(np.asarray(r.pose.lengths))
    return out


@pytest.fixture(scope="module")
def start(skel):
    """The true first pose with every length 1.15 times the truth's (within the ranges): a fit's error to keep."""
    p = true_pose(skel, 0)
    return p._replace(lengths=jnp.clip(p.lengths * 1.15, skel.length_lo, skel.length_hi))


def test_a_window_of_one_holds_the_lengths_of_the_start(skel, start):
    got = track_lengths(skel, dataclasses.replace(CFG, length_window=1.0), start)
    for lengths in got:
        np.testing.assert_array_equal(lengths, np.asarray(start.lengths))


def test_a_wider_window_bounds_each_frames_change(skel, start):
    w = 1.1
    got = track_lengths(skel, dataclasses.replace(CFG, length_window=w), start)
    prev = np.asarray(start.lengths)
    moved = False
    for lengths in got:
        ratio = lengths / prev
        assert np.all(ratio <= w * (1 + 1e-5)) and np.all(ratio >= (1 - 1e-5) / w), ratio
        moved |= bool(np.any(np.abs(ratio - 1) > 1e-4))
        prev = lengths
    assert moved  # the window was searched, or the test says nothing


def test_the_window_is_checked():
    with pytest.raises(jp.ConfigError, match="length_window"):
        TrackConfig(length_window=0.5).validate()
    with pytest.raises(jp.ConfigError, match="length_window"):
        TrackConfig(length_window=float("nan")).validate()
    TrackConfig(length_window=0.0).validate()
    TrackConfig(length_window=1.0).validate()


def test_a_known_scale_is_held_in_tracked_frames(skel):
    pred = true_pose(skel, 0)._replace(scale=jnp.float32(1.0))
    cfg = dataclasses.replace(CFG, fit=dataclasses.replace(CFG.fit, scale=0.97))
    b = local_bounds(skel, cfg, pred)
    assert float(b.lo[6]) == float(b.hi[6]) == np.float32(0.97)  # genome_layout: the scale is gene 6
    assert jp.genome_layout(skel).names[6] == "scale"
