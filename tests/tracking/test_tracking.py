"""Tracking (jaxpose.tracking): the pure ``track`` (one scan), the stateful ``Tracker``,
loss and recovery.  Oracles: the per-frame global ``fit`` (frame 0 and every
re-initialisation are that fit), a NumPy recomputation of the objective, the
truth of a synthetic motion, and ``track`` itself run per sequence (for vmap).

Every test shares one tiny configuration, so its programs compile once."""

from __future__ import annotations

import contextlib
import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxpose as jp
from jaxpose.objective import Cloud
from jaxpose.search import Fitter
from jaxpose.tracking import GLOBAL, LOST, MODES, TRACKED, TrackConfig, Tracker, track, track_batched
from oracles import brute_cost

N = 128  # points per cloud
T = 6  # frames
# the settings of `jaxpose track --islands 1 --population 16 --generations 25 --no-refine --track-population 12
# --track-generations 3 --track-refine-steps 8 --limb-sweep 0 --pivot-sweep 0 --max-points 128`, so
# that its test reuses these programs.  No sweeps in the global search: on a search this short they do most of the
# work, and a GA from fresh draws turns the round-off between differently compiled programs into different answers
# (docs/search.md, "Limb sweep").
FIT = jp.FitConfig(islands=1, population=16, generations=25, memetic_steps=0, final_refine_steps=0, limb_sweep=0,
                   pivot_sweep=0, turns=0)
CFG = TrackConfig(fit=FIT, population=12, generations=3, refine_steps=8)  # the tracked sweep: test_tracked_sweep
COMPILE_EVENT = "/jax/core/compile/backend_compile_duration"


@contextlib.contextmanager
def count_compiles():
    """The functions XLA compiles inside the block (one event per executable built)."""
    names: list[str] = []

    def listener(event, duration, **kwargs):
        if event == COMPILE_EVENT:
            names.append(str(kwargs.get("fun_name", "?")))

    jax.monitoring.register_event_duration_secs_listener(listener)
    try:
        yield names
    finally:
        jax.monitoring.unregister_event_duration_listener(listener)


@pytest.fixture(scope="module")
def skel():
    return jp.load_skeleton("spider")


def true_pose(skel, t: int, shift=(0.0, 0.0, 0.0)):
    """A spider 1 m in front of the camera, seen from above at an angle, legs moving a little per frame."""
    rest = jp.rest_pose(skel, root_t=(0.05 + shift[0], 0.1 + shift[1], 1.0 + shift[2]), root_rpy=(-2.2, 0.0, 0.3))
    wave = 0.06 * np.sin(0.4 * t + np.arange(skel.num_links * 3).reshape(-1, 3))
    angles = jnp.clip(rest.angles + wave, skel.angle_lo, skel.angle_hi)
    return rest._replace(angles=angles.astype(jnp.float32), root_t=rest.root_t + jnp.float32(0.004 * t))


def surface_cloud(skel, pose, seed: int) -> Cloud:
    """Points on the capsules' camera-facing halves (the camera at the origin looking along +z)."""
    links = jp.forward_kinematics(skel, pose)
    s, e, r = (np.asarray(a, np.float64) for a in (links.start, links.end, links.radius))
    rng = np.random.default_rng(seed)
    pts = []
    while len(pts) < N:
        i = rng.integers(len(s))
        axis = s[i] + rng.uniform() * (e[i] - s[i])
        d = rng.standard_normal(3)
        u = (e[i] - s[i]) / max(np.linalg.norm(e[i] - s[i]), 1e-9)
        d -= d.dot(u) * u
        p = axis + r[i] * d / np.linalg.norm(d)
        if np.dot(p - axis, p) < 0:  # faces the camera
            pts.append(p)
    return Cloud(jnp.asarray(np.array(pts), jnp.float32), jnp.ones(N, jnp.float32))


def empty_cloud() -> Cloud:
    return Cloud(jnp.zeros((N, 3), jnp.float32), jnp.zeros(N, jnp.float32))


def stack(clouds) -> Cloud:
    return Cloud(jnp.stack([c.points for c in clouds]), jnp.stack([c.weights for c in clouds]))


@pytest.fixture(scope="module")
def motion(skel):
    """T frames of smooth motion, then the subject out of view for a frame, then back 0.5 m away."""
    clouds = [surface_cloud(skel, true_pose(skel, t), t) for t in range(T)]
    truth = [true_pose(skel, t) for t in range(T)]
    back = true_pose(skel, T + 1, shift=(0.5, 0.0, 0.3))
    return clouds + [empty_cloud(), surface_cloud(skel, back, 99)], truth + [None, back]


track_jit = jax.jit(track, static_argnames="config")


@pytest.fixture(scope="module")
def tracked(skel, motion):
    return track_jit(stack(motion[0]), skel, jax.random.key(3), CFG)


def link_errors(skel, result, pose):
    """Largest capsule-end error (m), symmetric over the spider's legs (its 4-fold turn)."""
    from jaxpose.metrics import evaluate

    want = jp.forward_kinematics(skel, pose)
    e = evaluate(np.asarray(result.links.start), np.asarray(result.links.end), np.asarray(want.start),
                 np.asarray(want.end), skel)
    return e["symmetric"]["mpjpe_mm"] / 1000, e["symmetric"]["pcp"]


def frame(frames, t):
    return jax.tree_util.tree_map(lambda a: a[t], frames)


fit_jit = jax.jit(jp.fit, static_argnames="config")


def global_fit(skel, cloud, t: int):
    """The documented oracle of a global frame: fit with the first half of fold_in(key, t)."""
    key = jax.random.split(jax.random.fold_in(jax.random.key(3), t))[0]
    return fit_jit(cloud, skel, key, CFG.for_skeleton(skel).fit)


def scaled(skel, pose):
    """The skeleton a re-initialisation searches (TrackConfig.keep_scale), recomputed in NumPy: the
    scale range narrowed to scale_window about ``pose``'s scale, the rest the skeleton's."""
    s, w = float(pose.scale), CFG.scale_window
    lo, hi = float(skel.scale_lo), float(skel.scale_hi)
    s_lo = min(max(s / w, lo), hi)
    return dataclasses.replace(skel, scale_lo=jnp.float32(s_lo), scale_hi=jnp.float32(min(max(s * w, s_lo), hi)))


@pytest.mark.parametrize("t", [0, T + 1])
def test_global_frames_are_the_per_frame_fit(skel, motion, tracked, t):
    """Frame 0 is the global search's fit of that frame alone; the first frame after a lost one
    is that fit with the scale of the last fitted frame (T - 1) kept."""
    fitted = skel if t == 0 else scaled(skel, frame(tracked, T - 1).result.pose)
    if t:
        assert float(fitted.scale_hi) < float(skel.scale_hi) and float(fitted.scale_lo) > float(skel.scale_lo)
    want = global_fit(fitted, motion[0][t], t)
    got = frame(tracked, t)
    assert int(got.mode) == GLOBAL
    np.testing.assert_allclose(np.asarray(got.result.links.end), np.asarray(want.links.end), atol=1e-4)
    np.testing.assert_allclose(float(got.result.cost), float(want.cost), rtol=1e-4)
    np.testing.assert_allclose(np.asarray(got.result.history), np.asarray(want.history), rtol=1e-4)


def test_subject_skeleton_keeps_the_last_fitted_scale(skel, tracked):
    """Before any fitted frame, or with keep_scale off, the global search gets the skeleton's own
    ranges; after one, the scale window about that frame's scale (``scaled``)."""
    from jaxpose.tracking import initial_state
    from jaxpose.tracking.step import subject_skeleton

    def ranges(sk):
        return [np.asarray(a) for a in (sk.scale_lo, sk.scale_hi, sk.length_lo, sk.length_hi)]

    fresh = initial_state(skel, jax.random.key(0))
    for got, want in zip(ranges(subject_skeleton(skel, CFG, fresh)), ranges(skel)):
        np.testing.assert_array_equal(got, want)
    last = frame(tracked, T - 1).result.pose
    state = initial_state(skel, jax.random.key(0), init=last)
    for got, want in zip(ranges(subject_skeleton(skel, CFG, state)), ranges(scaled(skel, last))):
        np.testing.assert_allclose(got, want, rtol=1e-6)
    off = dataclasses.replace(CFG, keep_scale=False)
    for got, want in zip(ranges(subject_skeleton(skel, off, state)), ranges(skel)):
        np.testing.assert_array_equal(got, want)


def test_a_frame_without_the_subject_is_lost(tracked):
    modes = np.asarray(tracked.mode)
    assert modes[0] == GLOBAL and np.all(modes[1:T] == TRACKED), modes
    lost = frame(tracked, T)
    assert int(lost.mode) == LOST and int(lost.points) == 0
    assert np.all(np.isnan(np.asarray(lost.result.links.end))) and np.isnan(float(lost.result.cost))
    assert int(lost.result.objective_evaluations) == 0 and np.isnan(float(lost.tracked_cost))
    r = frame(tracked, 1).result
    # the local GA, then the limb sweep's GA on sweep_limbs of the spider's 8 limbs; no sweep Adam (FIT has
    # the final refinement off, which turns the sweep's polish off too)
    assert int(r.objective_evaluations) == CFG.population * (CFG.generations + CFG.sweep_limbs * CFG.sweep_generations)
    assert int(r.gradient_evaluations) == CFG.refine_top * CFG.refine_steps


@pytest.fixture(scope="module")
def from_truth(skel, motion):
    """A Tracker started from frame 0's true pose, through the motion, the lost frame and the return."""
    clouds, truth = motion
    tr = Tracker(skel, CFG, key=jax.random.key(3), init=truth[0])
    out = [(tr.update(clouds[0]), tr.mode)]
    with count_compiles() as compiled:
        out += [(tr.update(c), tr.mode) for c in clouds[1:T + 1]]  # tracked frames, then the lost one
    back = tr.update(clouds[T + 1])  # the return: the global search (its programs compile here)
    return tr, out + [(back, tr.mode)], compiled


def test_tracked_frames_follow_the_true_motion(skel, motion, from_truth):
    _, truth = motion
    _, out, _ = from_truth
    assert [m for _, m in out] == ["tracked"] * T + ["lost", "global"]
    for t in range(T):
        mpjpe, pcp = link_errors(skel, out[t][0], truth[t])
        assert pcp == 1.0 and mpjpe < 0.015, (t, mpjpe, pcp)


def test_a_tracked_cost_is_the_objective_alone(skel, motion, from_truth):
    """The reported cost leaves the motion prior out: at least NumPy's data term of the
    returned links (the other terms are non-negative), and within the free-space and
    collision terms' reach of it."""
    clouds, _ = motion
    for t in (1, 2, 3):
        r = from_truth[1][t][0]
        sigma = float(jp.cloud_spread(clouds[t])) * FIT.objective.sigma_factor
        data = brute_cost(np.asarray(clouds[t].points), np.asarray(clouds[t].weights), np.asarray(r.links.start),
                          np.asarray(r.links.end), np.asarray(r.links.radius), sigma=sigma)
        assert data - 1e-5 <= float(r.cost) <= data + 0.05, (t, data, float(r.cost))


def test_tracker_update_never_recompiles(skel, motion, from_truth):
    clouds, _ = motion
    tr, _, compiled = from_truth
    assert compiled == [], compiled  # tracked frames and a lost one after the first update
    with count_compiles() as again:
        tr.reset()
        for c in clouds:  # tracked, lost, and a global search: all compiled already
            tr.update(c)
    assert again == [], again


def test_tracker_is_deterministic_and_matches_track(skel, motion, tracked):
    """Same seed, same frames: bit-identical; and the modes of track, its links equal to rounding
    (the Tracker runs the global search as a Fitter, track as one traced fit)."""
    clouds, _ = motion
    runs = []
    for _ in range(2):
        tr = Tracker(skel, CFG, key=jax.random.key(3))
        runs.append([(tr.update(c), tr.mode) for c in clouds])
    for (a, _), (b, _) in zip(*runs):
        np.testing.assert_array_equal(np.asarray(a.links.end), np.asarray(b.links.end))
        np.testing.assert_array_equal(np.asarray(a.cost), np.asarray(b.cost))
    assert [m for _, m in runs[0]] == [MODES[int(m)] for m in np.asarray(tracked.mode)]
    ends = np.stack([np.asarray(r.links.end) for r, _ in runs[0]])
    np.testing.assert_allclose(ends, np.asarray(tracked.result.links.end), atol=5e-3)


def test_a_jump_in_cost_reinitialises(skel):
    """The subject teleports 0.4 m between two frames: the local search cannot follow, its cost
    jumps above loss_ratio times the recent cost, and the global search takes the frame."""
    clouds = [surface_cloud(skel, true_pose(skel, t), t) for t in range(3)]
    clouds.append(surface_cloud(skel, true_pose(skel, 3, shift=(0.4, -0.3, 0.3)), 7))
    clouds += [empty_cloud()] * (T + 2 - len(clouds))  # the shapes of the shared program
    frames = track_jit(stack(clouds), skel, jax.random.key(3), CFG)
    modes = np.asarray(frames.mode)
    assert list(modes[:4]) == [GLOBAL, TRACKED, TRACKED, GLOBAL], modes
    assert float(frames.tracked_cost[3]) > CFG.loss_ratio * float(frames.result.cost[2])
    assert float(frames.result.cost[3]) < float(frames.tracked_cost[3])
    want = global_fit(scaled(skel, frame(frames, 2).result.pose), clouds[3], 3)  # the subject's scale kept
    np.testing.assert_allclose(np.asarray(frames.result.links.end[3]), np.asarray(want.links.end), atol=1e-4)


# the recheck tests' cases (a global fit cheaper or not, by less than a margin) are set up with the
# global search over the skeleton's whole ranges; the kept scale has tests of its own (above)
CFG_R = dataclasses.replace(CFG, keep_scale=False)


def _run_pair(skel, clouds, init=None):
    """The same frames through a Tracker without rechecks and one with ``recheck_every=2``:
    ``(plain results, plain modes, rechecked results, rechecked modes)``."""
    key = jax.random.key(3)
    plain = Tracker(skel, CFG_R, key=key, init=init)
    rechecked = Tracker(skel, dataclasses.replace(CFG_R, recheck_every=2), key=key, init=init)
    out = ([], [], [], [])
    for c in clouds:
        out[0].append(plain.update(c))
        out[1].append(plain.mode)
        out[2].append(rechecked.update(c))
        out[3].append(rechecked.mode)
    return out


def _recheck_oracle(skel, cloud, t: int):
    """The global search of frame ``t`` with its documented key, run as the Tracker runs it."""
    return Fitter(skel, CFG.for_skeleton(skel).fit).run(cloud, jax.random.split(jax.random.fold_in(
        jax.random.key(3), t))[0])


def test_a_recheck_that_finds_a_cheaper_fit_takes_it(skel, motion):
    """Tracked from a pose turned upside down (the local search cannot turn it over, and its cost
    stays level, so the loss test does not fire): two frames after the start the recheck runs the
    global search and its fit (the oracle: a Fitter with the frame's documented key) replaces the
    wrong one; without rechecks every frame stays tracked and wrong."""
    clouds, truth = motion
    start = truth[0]._replace(root_rpy=truth[0].root_rpy + jnp.asarray([np.pi, 0.0, 0.0], jnp.float32))
    plain, plain_modes, got, modes = _run_pair(skel, clouds[:4], init=start)
    assert plain_modes == ["tracked"] * 4, plain_modes
    assert modes == ["tracked", "tracked", "global", "tracked"], modes  # frame 0 (tracked from init) is no recheck
    want = _recheck_oracle(skel, clouds[2], 2)
    assert float(want.cost) < float(plain[2].cost)  # the case under test: the global fit is the cheaper
    assert float(got[2].cost) == float(want.cost)
    np.testing.assert_array_equal(np.asarray(got[2].links.end), np.asarray(want.links.end))
    assert float(got[3].cost) < float(plain[3].cost)  # tracking goes on from the better fit
    assert link_errors(skel, got[3], truth[3])[0] < link_errors(skel, plain[3], truth[3])[0]


def test_a_recheck_that_finds_nothing_cheaper_changes_nothing(skel, motion):
    """Tracked from the true first pose the local search tracks well: the recheck's global fit
    (the oracle) is dearer, the frame keeps the local fit, and the motion model and the recent cost
    carry on as after a tracked frame, so the next frame equals that of a Tracker without rechecks.
    (Started from the truth, not from frame 0's small global search, whose answer, and with it
    the case under test, hangs on round-off.)"""
    clouds, truth = motion
    plain, plain_modes, got, modes = _run_pair(skel, clouds[:4], init=truth[0])
    assert plain_modes == ["tracked"] * 4, plain_modes
    assert modes == ["tracked", "tracked", "global", "tracked"], modes  # frame 0 (tracked from init) is no recheck
    assert float(_recheck_oracle(skel, clouds[2], 2).cost) > float(plain[2].cost)  # the case under test
    for t in (1, 2, 3):
        assert float(got[t].cost) == float(plain[t].cost), t
        np.testing.assert_array_equal(np.asarray(got[t].links.end), np.asarray(plain[t].links.end))


def test_a_recheck_margin_keeps_the_tracked_fit_unless_the_global_one_is_that_much_cheaper():
    """The decision against a plain Python oracle over every case: a recheck's global fit replaces
    the local one only below ``(1 - margin)`` times its cost, any other global fit when cheaper,
    a NaN global cost never, and a frame without a local fit always takes the global one."""
    from jaxpose.tracking.step import keeps_local

    def oracle(run_local, run_global, recheck, local, glob, margin):
        if not run_global:
            return True
        if not run_local:
            return False
        return not glob < local * ((1 - margin) if recheck else 1.0)

    for margin in (0.0, 0.1):
        for run_local in (False, True):
            for run_global in (False, True):
                for recheck in (False, True):
                    for glob in (0.5, 0.85, 0.95, 1.0, 1.2, float("nan")):
                        got = bool(keeps_local(jnp.asarray(run_local), jnp.asarray(run_global), jnp.asarray(recheck),
                                               jnp.float32(1.0), jnp.float32(glob), margin))
                        assert got == oracle(run_local, run_global, recheck, 1.0, glob, margin), \
                            (margin, run_local, run_global, recheck, glob)


def test_a_recheck_within_its_margin_changes_nothing(skel, motion):
    """The upside-down start of the test above, whose recheck takes the global fit without a
    margin: with a margin above that fit's saving the frame keeps the local fit and every frame
    equals a Tracker's without rechecks."""
    clouds, truth = motion
    start = truth[0]._replace(root_rpy=truth[0].root_rpy + jnp.asarray([np.pi, 0.0, 0.0], jnp.float32))
    key = jax.random.key(3)
    plain = Tracker(skel, CFG_R, key=key, init=start)
    want = [plain.update(c) for c in clouds[:4]]
    saving = 1.0 - float(_recheck_oracle(skel, clouds[2], 2).cost) / float(want[2].cost)
    assert 0.0 < saving < 0.9  # the case under test: the global fit is cheaper, by less than the margin
    margined = Tracker(skel, dataclasses.replace(CFG_R, recheck_every=2, recheck_margin=0.9), key=key, init=start)
    for t, c in enumerate(clouds[:4]):
        got = margined.update(c)
        assert margined.mode == ("global" if t == 2 else "tracked"), (t, margined.mode)
        assert float(got.cost) == float(want[t].cost), t
        np.testing.assert_array_equal(np.asarray(got.links.end), np.asarray(want[t].links.end))


@pytest.fixture(scope="module")
def two_sequences(skel, motion, tracked):
    """``motion`` (lost at frame T, back by the global search at T + 1) beside a sequence tracked
    throughout: ``(both clouds (2, T + 2, ...), keys, each sequence tracked on its own)``."""
    other = stack([surface_cloud(skel, true_pose(skel, t + 2), 50 + t) for t in range(T + 2)])
    both = jax.tree_util.tree_map(lambda a, b: jnp.stack([a, b]), stack(motion[0]), other)
    keys = jnp.stack([jax.random.key(3), jax.random.key(4)])
    return both, keys, (tracked, track_jit(other, skel, jax.random.key(4), CFG))


def _assert_each_sequence(batch, singles):
    """The same modes; a tracked frame keeps its local fit; the global frames (the same keys)
    to 2 mm; the tracked ones, whose tiny searches amplify the round-off of another compiled
    program from frame to frame (seen: up to 13 mm and 4% of cost), to 2 cm and 6% of cost."""
    for b, want in enumerate(singles):
        got = jax.tree_util.tree_map(lambda a: a[b], batch)
        mode = np.asarray(want.mode)
        np.testing.assert_array_equal(np.asarray(got.mode), mode)
        tracked = mode == TRACKED
        np.testing.assert_array_equal(np.asarray(got.result.cost)[tracked], np.asarray(got.tracked_cost)[tracked])
        end, want_end = np.asarray(got.result.links.end), np.asarray(want.result.links.end)
        np.testing.assert_allclose(end[mode == GLOBAL], want_end[mode == GLOBAL], atol=2e-3)
        np.testing.assert_allclose(end, want_end, atol=2e-2)
        np.testing.assert_allclose(np.asarray(got.result.cost), np.asarray(want.result.cost), rtol=6e-2)


def test_track_batched_equals_each_sequence(skel, two_sequences):
    """The batch's global search runs at frame 0 (both), at T + 1 (the first sequence only: the
    second keeps its tracked fit) and nowhere else; every frame equals its sequence's own track."""
    both, keys, singles = two_sequences
    modes = [np.asarray(s.mode) for s in singles]
    assert modes[0][T] == LOST and modes[0][T + 1] == GLOBAL and modes[1][T + 1] == TRACKED  # the case under test
    batch = jax.jit(track_batched, static_argnames="config")(both, skel, keys, CFG)
    _assert_each_sequence(batch, singles)


def test_track_batch_in_chunks_equals_each_sequence(skel, two_sequences):
    """``parallel.track_batch`` three frames at a time (the states carried from call to call, the
    last chunk of two padded with empty frames) tracks each sequence as it is tracked alone, and
    reports its progress after every chunk."""
    from jaxpose.parallel import device_mesh, track_batch, track_batch_chunks

    both, keys, singles = two_sequences
    seen = []
    batch = track_batch(both, skel, keys, CFG, device_mesh(1), chunk=3, progress=lambda *a: seen.append(a))
    assert seen == [(3, T + 2), (6, T + 2), (T + 2, T + 2)]
    _assert_each_sequence(batch, singles)
    with pytest.raises(jp.ConfigError, match="chunk must be a whole number >= 1, got 0"):
        track_batch(both, skel, keys, CFG, device_mesh(1), chunk=0)
    with pytest.raises(jp.ConfigError, match="got 0"):  # at the call, before any frame is asked for
        track_batch_chunks(both, skel, keys, CFG, device_mesh(1), chunk=0)
    with pytest.raises(jp.ConfigError, match="at least one frame"):
        track_batch_chunks(jax.tree_util.tree_map(lambda x: x[:, :0], both), skel, keys, CFG, device_mesh(1))


@pytest.mark.slow  # a fourth compile of the whole search (about 25 s on 2 cores)
def test_track_under_vmap_equals_each_sequence(skel, two_sequences):
    both, keys, singles = two_sequences
    batch = jax.jit(jax.vmap(track, in_axes=(0, None, 0, None)), static_argnames="config")(both, skel, keys, CFG)
    _assert_each_sequence(batch, singles)


def test_config_is_checked():
    with pytest.raises(jp.ConfigError, match="loss_ratio"):
        TrackConfig(loss_ratio=0.5).validate()
    with pytest.raises(jp.ConfigError, match="generations"):
        TrackConfig(generations=0).validate()
    with pytest.raises(jp.ConfigError, match="recheck_every"):
        TrackConfig(recheck_every=-1).validate()
    with pytest.raises(jp.ConfigError, match="recheck_margin"):
        TrackConfig(recheck_margin=1.0).validate()
    with pytest.raises(jp.ConfigError, match="velocity"):
        TrackConfig(velocity=2.0).validate()
    with pytest.raises(jp.ConfigError, match="population"):
        TrackConfig(fit=dataclasses.replace(FIT, population=1)).validate()
