"""One frame of tracking (:func:`track_step`), a sequence (:func:`track`, one
``lax.scan``) and the stateful :class:`Tracker` for a live stream.

A frame with fewer than ``min_points`` points is *lost*: nothing is fitted, the
result is NaN, and the next frame with the subject starts anew.  Otherwise, when
the last frame was fitted, the motion model predicts this frame's pose and the
local search (:func:`~jaxpose.tracking.local.local_fit`) fits it (*tracked*).  When
there is no last pose, or the tracked cost exceeds ``loss_ratio`` times the recent
cost, the global search (:func:`~jaxpose.search.fit`) fits the frame (*global*) and
the better of the two results is kept; once a frame was fitted, that search keeps the
subject's scale (:func:`subject_skeleton`).  When ``recheck_every`` frames have passed since
the global search last ran, it runs beside the local one too (a recheck), the better
result kept.

Random numbers: frame ``t`` uses ``jax.random.fold_in(key, t)``, split in two: the
first key for the global search, the second for the local one; so a frame's global
fit is ``fit(cloud, skeleton, split(fold_in(key, t))[0], config.fit)``.

Under ``jax.vmap`` the branches become selects: every frame of a batch of sequences
would pay for the global search.  :func:`track_batched` tracks a batch with the
global search run only on the frames where some sequence of the batch needs it.
"""

from __future__ import annotations

import dataclasses
import time
from typing import NamedTuple

import jax
import jax.numpy as jnp

from ..genome import genome_layout, pose_to_vector, vector_to_pose, window
from ..geometry import matrix_to_rpy, rpy_matrix
from ..kinematics import forward_kinematics
from ..objective import Cloud
from ..search import FitResult, Fitter, fit
from ..search.sweep import SWEEP_REFINE_TOP, sweep_masks
from ..skeleton import Pose, Skeleton
from .config import TrackConfig
from .local import SCALE, local_fit

GLOBAL, TRACKED, LOST = 0, 1, 2
MODES = ("global", "tracked", "lost")  # TrackFrame.mode's names


class TrackState(NamedTuple):
    """What carries from one frame to the next."""

    pose: jax.Array  # (7 + 4 L,) the last fitted pose (genome.pose_to_vector)
    velocity: jax.Array  # (7 + 4 L,) its change over the last frame; [3:6]: the turn's roll, pitch, yaw
    reference: jax.Array  # () the recent cost (moving average)
    valid: jax.Array  # () bool: the last frame was fitted
    frame: jax.Array  # () int32: frames seen
    key: jax.Array
    last_global: jax.Array  # () int32: the last frame the global search fitted (0 before any)


class TrackFrame(NamedTuple):
    """One frame's outcome (stacked along the frames by :func:`track`)."""

    result: FitResult  # NaN for a lost frame
    mode: jax.Array  # () int32: GLOBAL, TRACKED or LOST (MODES)
    points: jax.Array  # () int32: the cloud's points (weight > 0)
    tracked_cost: jax.Array  # () the local search's cost before any recovery (NaN when it did not run)


def initial_state(skel: Skeleton, key: jax.Array, init: Pose | None = None) -> TrackState:
    """The state before the first frame: no pose yet (the first frame runs the global
    search), or the pose ``init`` (camera frame) when it is known (the first frame is tracked from it)."""
    n = 7 + 4 * skel.num_links
    zeros = jnp.zeros((n,), jnp.float32)
    pose = zeros if init is None else pose_to_vector(init).astype(jnp.float32)
    return TrackState(pose, zeros, jnp.asarray(jnp.inf, jnp.float32), jnp.asarray(init is not None),
                      jnp.asarray(0, jnp.int32), key, jnp.asarray(0, jnp.int32))


def predict(skel: Skeleton, config: TrackConfig, state: TrackState) -> tuple[Pose, Pose]:
    """``(prediction, last pose)``: constant velocity, damped by ``config.velocity`` (the lengths
    unchanged when ``config.length_window`` is set)."""
    L = skel.num_links
    last = vector_to_pose(state.pose, L)
    pred = vector_to_pose(state.pose + config.velocity * state.velocity, L)
    R = rpy_matrix(config.velocity * state.velocity[3:6]) @ rpy_matrix(last.root_rpy)
    angles = jnp.clip(pred.angles, skel.angle_lo, skel.angle_hi)
    lengths = last.lengths if config.length_window else jnp.clip(pred.lengths, skel.length_lo, skel.length_hi)
    return pred._replace(root_rpy=matrix_to_rpy(R), angles=angles, lengths=lengths, scale=last.scale), last


def subject_skeleton(skel: Skeleton, config: TrackConfig, state: TrackState) -> Skeleton:
    """The skeleton the global search fits: ``skel``, or, with ``config.keep_scale`` once a frame
    was fitted (the last pose's scale is then positive), its scale range narrowed to
    ``scale_window`` about the last fitted frame's (the subject that comes back is the same size;
    its lengths are searched again: docs/tracking.md, "Re-initialisations keep the scale")."""
    if not config.keep_scale:
        return skel
    s = state.pose[SCALE]
    known = s > 0
    lo, hi = window(s, skel.scale_lo, skel.scale_hi, config.scale_window)
    return dataclasses.replace(skel, scale_lo=jnp.where(known, lo, skel.scale_lo),
                               scale_hi=jnp.where(known, hi, skel.scale_hi))


def change(old: jax.Array, new: jax.Array) -> jax.Array:
    """The velocity between two pose vectors (the root's turn as the roll, pitch, yaw of ``R_new R_old^T``)."""
    turn = matrix_to_rpy(rpy_matrix(new[3:6]) @ rpy_matrix(old[3:6]).T)
    return (new - old).at[3:6].set(turn)


def _nan_result(skel: Skeleton, config: TrackConfig) -> FitResult:
    n = 7 + 4 * skel.num_links
    pose = vector_to_pose(jnp.full((n,), jnp.nan, jnp.float32), skel.num_links)
    nan = jnp.asarray(jnp.nan, jnp.float32)
    zero = jnp.asarray(0, jnp.int32)
    return FitResult(pose, jnp.full((genome_layout(skel).size,), jnp.nan, jnp.float32),
                     forward_kinematics(skel, pose), nan, jnp.full((config.fit.generations,), jnp.nan, jnp.float32),
                     zero, zero, jnp.asarray(0.0, jnp.float32), jnp.asarray(0.0, jnp.float32))


def _tracked_result(skel: Skeleton, config: TrackConfig, cloud: Cloud, pred: Pose, last: Pose, key,
                    frame) -> FitResult:
    """The local search's outcome as a :class:`FitResult` (history padded with its last
    cost to the global search's length, as a time-budgeted fit's is)."""
    r = local_fit(skel, config, cloud, pred, last, key, frame)
    G = config.fit.generations
    h = r.history[:G]
    history = jnp.concatenate([h, jnp.full((G - h.shape[0],), h[-1])]) if h.shape[0] < G else h
    evals, grads = tracked_counts(skel, config)
    dist = jnp.float32(evals + grads) * cloud.points.shape[0] * skel.num_links
    return FitResult(r.pose, r.genome, r.links, r.cost, history, jnp.asarray(evals, jnp.int32),
                     jnp.asarray(grads, jnp.int32), dist, jnp.asarray(0.0, jnp.float32))


def tracked_counts(skel: Skeleton, config: TrackConfig) -> tuple[int, int]:
    """``(objective evaluations, gradient evaluations)`` of one tracked frame: the local
    search, its refinement and the limb sweep."""
    n = min(config.sweep_limbs, len(sweep_masks(skel)))
    top = min(SWEEP_REFINE_TOP, config.population)
    steps = config.sweep_steps if config.fit.final_refine_on else 0
    evals = config.population * (config.generations + n * config.sweep_generations)
    return evals, config.refine_count * config.refine_steps + n * top * steps


def _select(c, a, b):
    return jax.tree_util.tree_map(lambda x, y: jnp.where(c, x, y), a, b)


class _Pending(NamedTuple):
    """A frame between the local search and the decision on the global one."""

    local: FitResult
    points: jax.Array
    present: jax.Array
    run_local: jax.Array
    run_global: jax.Array
    recheck: jax.Array  # the global search runs as a recheck (TrackConfig.recheck_every)
    key: jax.Array  # the global search's key


def _local_part(skel: Skeleton, config: TrackConfig, state: TrackState, cloud: Cloud) -> _Pending:
    """The points, the local search when there is a last pose, and whether the global search must run."""
    k_global, k_local = jax.random.split(jax.random.fold_in(state.key, state.frame))
    points = jnp.sum(cloud.weights > 0).astype(jnp.int32)
    present = points >= config.min_points
    pred, last = predict(skel, config, state)
    run_local = present & state.valid
    local = jax.lax.cond(run_local, lambda: _tracked_result(skel, config, cloud, pred, last, k_local,
                                                                        state.frame),
                         lambda: _nan_result(skel, config))
    lost = ~(local.cost <= config.loss_ratio * state.reference)  # NaN (not run) counts as lost
    due = (state.frame - state.last_global >= config.recheck_every) if config.recheck_every else jnp.asarray(False)
    recheck = run_local & due
    return _Pending(local, points, present, run_local, present & (~state.valid | lost | recheck), recheck, k_global)


def keeps_local(run_local, run_global, recheck, local_cost, global_cost, margin: float) -> jax.Array:
    """Whether a frame keeps its local fit: the global one replaces it unless dearer (a NaN
    global cost never replaces a fitted frame), and on a recheck only when cheaper by ``margin``."""
    bar = local_cost * jnp.where(recheck, 1.0 - margin, 1.0)
    return run_local & ~(global_cost < bar) | ~run_global


def _finish_part(config: TrackConfig, state: TrackState, p: _Pending, glob: FitResult):
    """This frame's result (the better of the local and the global one, NaN when lost) and the next state."""
    none = jax.tree_util.tree_map(lambda x: jnp.full_like(x, jnp.nan) if x.dtype.kind == "f" else jnp.zeros_like(x),
                                  p.local)._replace(distance_evaluations=jnp.float32(0), wall_time=jnp.float32(0))
    keep_local = keeps_local(p.run_local, p.run_global, p.recheck, p.local.cost, glob.cost, config.recheck_margin)
    result = _select(p.present, _select(keep_local, p.local, glob), none)
    mode = jnp.where(~p.present, LOST, jnp.where(p.run_global, GLOBAL, TRACKED)).astype(jnp.int32)
    new_pose = pose_to_vector(result.pose)
    # a recheck that kept the local fit continues the motion as a tracked frame does
    continued = (mode == TRACKED) | (p.recheck & keep_local)
    velocity = jnp.where(continued, change(state.pose, new_pose), 0.0)
    m = config.cost_memory
    reference = jnp.where(continued, m * state.reference + (1 - m) * result.cost, result.cost)
    last_global = jnp.where(mode == GLOBAL, state.frame, state.last_global).astype(jnp.int32)
    next_state = TrackState(jnp.where(p.present, new_pose, state.pose), velocity,
                            jnp.where(p.present, reference, jnp.inf), p.present, state.frame + 1, state.key,
                            last_global)
    return next_state, TrackFrame(result, mode, p.points, p.local.cost)


def _as_cloud(cloud: Cloud) -> Cloud:
    return Cloud(jnp.asarray(cloud.points, jnp.float32), jnp.asarray(cloud.weights, jnp.float32))


def track_step(skel: Skeleton, config: TrackConfig, state: TrackState, cloud: Cloud) -> tuple[TrackState, TrackFrame]:
    """One frame: ``(next state, this frame's outcome)``.  ``config`` must be resolved
    (:meth:`TrackConfig.for_skeleton`); pure and jit-compatible (``config`` static)."""
    cloud = _as_cloud(cloud)
    p = _local_part(skel, config, state, cloud)
    glob = jax.lax.cond(p.run_global,
                        lambda: _wall0(fit(cloud, subject_skeleton(skel, config, state), p.key, config.fit)),
                        lambda: _nan_result(skel, config))
    return _finish_part(config, state, p, glob)


def _wall0(r: FitResult) -> FitResult:
    return r._replace(wall_time=jnp.asarray(r.wall_time, jnp.float32))


def track(clouds: Cloud, skeleton: Skeleton, key: jax.Array, config: TrackConfig = TrackConfig(),
          init: Pose | None = None) -> TrackFrame:
    """Track ``skeleton`` through a stack of clouds (``points (T, N, 3)``, ``weights
    (T, N)``, camera frame): frame 0 (and every frame after a lost one, every
    recovery and every recheck) by the global search, the others from the last pose (``init``: a known
    pose to track frame 0 from instead).  Returns every frame's :class:`TrackFrame`,
    stacked along T.

    Pure and jit-compatible (``config`` static); vmappable over sequences and keys, though
    under ``vmap`` every frame pays for the global search: :func:`track_batched` does not::

        track_jit = jax.jit(track, static_argnames="config")
        frames = track_jit(clouds, skel, key, config)
    """
    config = config.validate().for_skeleton(skeleton)
    _, frames = jax.lax.scan(lambda s, c: track_step(skeleton, config, s, c), initial_state(skeleton, key, init),
                             clouds)
    return frames


def track_batched(clouds: Cloud, skeleton: Skeleton, keys: jax.Array, config: TrackConfig = TrackConfig(),
                  init: Pose | None = None) -> TrackFrame:
    """:func:`track` of ``S`` sequences at once (``points (S, T, N, 3)``, ``weights (S, T, N)``,
    ``keys (S,)``): each sequence's frames equal its own :func:`track` to rounding, leaves
    ``(S, T, ...)``.  Unlike ``jax.vmap(track)``, whose branches become selects, a frame runs the
    global search (for the whole batch, its results kept where needed) only when some sequence
    needs it.  Pure and jit-compatible (``config`` static)."""
    states = jax.vmap(lambda k: initial_state(skeleton, k, init))(keys)
    return track_batched_from(states, clouds, skeleton, config)[1]


def track_batched_from(states: TrackState, clouds: Cloud, skeleton: Skeleton,
                       config: TrackConfig = TrackConfig()) -> tuple[TrackState, TrackFrame]:
    """:func:`track_batched` from the states ``(S,)`` its sequences reached (``initial_state``
    vmapped over keys, or a previous call's): ``(the states after these frames, their frames)``,
    so that a batch can run a few frames at a time with the same results."""
    config = config.validate().for_skeleton(skeleton)

    def step(states, cloud):
        p = jax.vmap(lambda s, c: _local_part(skeleton, config, s, c))(states, cloud)
        nothing = jax.tree_util.tree_map(lambda x: jnp.broadcast_to(x, (len(p.key), *x.shape)),
                                         _nan_result(skeleton, config))
        def global_fits():
            skels = jax.vmap(lambda s: subject_skeleton(skeleton, config, s))(states)
            return jax.vmap(lambda c, sk, k: _wall0(fit(c, sk, k, config.fit)))(cloud, skels, p.key)

        glob = jax.lax.cond(jnp.any(p.run_global), global_fits, lambda: nothing)
        return jax.vmap(lambda s, q, g: _finish_part(config, s, q, g))(states, p, glob)

    time_major = jax.tree_util.tree_map(lambda x: jnp.swapaxes(x, 0, 1), _as_cloud(clouds))
    states, frames = jax.lax.scan(step, states, time_major)
    return states, jax.tree_util.tree_map(lambda x: jnp.swapaxes(x, 0, 1), frames)


_local_jit = jax.jit(_local_part, static_argnames="config")
_finish_jit = jax.jit(_finish_part, static_argnames="config")
_subject_jit = jax.jit(subject_skeleton, static_argnames="config")


class Tracker:
    """Live tracking: :meth:`update` fits each new cloud from the last one.

    A tracked frame runs one compiled program (the local search and the loss test,
    :func:`track_step`'s first half) and a small one that keeps the result; both are
    compiled by the first update and reused by every frame of the same cloud size
    (``max_points``).  The global search (frame 0, recovery, recheck) runs as a
    :class:`~jaxpose.search.Fitter`, compiled once too, with the keys :func:`track`
    uses: the same steps as :func:`track`'s, compiled apart (so equal to rounding)."""

    def __init__(self, skeleton: Skeleton, config: TrackConfig = TrackConfig(), seed: int = 0,
                 key: jax.Array | None = None, init: Pose | None = None):
        self.skeleton = skeleton
        self.init = init
        self.config = config.validate().for_skeleton(skeleton)
        self.key = jax.random.key(seed) if key is None else key
        self._none = _nan_result(skeleton, self.config)
        self.reset()

    def reset(self) -> None:
        """Start again: the next frame is frame 0 (tracked from ``init`` when it was given, else
        fitted by the global search)."""
        self.state = initial_state(self.skeleton, self.key, self.init)
        self.last = None

    def update(self, cloud: Cloud, progress=None) -> FitResult:
        """Fit one cloud; returns its :class:`FitResult` (NaN when the frame is lost), with
        ``wall_time`` the seconds this update took.  :attr:`mode` says how it was fitted;
        ``progress(generation, best, evaluations)`` reports a global search's epochs."""
        t0 = time.perf_counter()
        cloud = _as_cloud(cloud)
        p = _local_jit(self.skeleton, self.config, self.state, cloud)
        glob = self._none
        if bool(p.run_global):
            # the programs are compiled once: a narrowed skeleton (keep_scale) reuses them
            skel = _subject_jit(self.skeleton, self.config, self.state)
            glob = Fitter(skel, self.config.fit).run(cloud, p.key, progress)
        self.state, frame = jax.block_until_ready(_finish_jit(self.config, self.state, p, glob))
        self.last = frame._replace(result=frame.result._replace(
            wall_time=jnp.asarray(time.perf_counter() - t0, jnp.float32)))
        return self.last.result

    @property
    def mode(self) -> str | None:
        """``"global"``, ``"tracked"`` or ``"lost"``: how the last update was fitted (None before any)."""
        return None if self.last is None else MODES[int(self.last.mode)]

    @property
    def frame(self) -> int:
        """Frames seen so far."""
        return int(self.state.frame)
