"""Many fits on many devices: a batch of images sharded over a :class:`~jax.sharding.Mesh`.

:func:`fit_batch` runs :func:`~jaxpose.search.fit` vmapped over clouds and keys as
one program compiled for the whole mesh (``shard_map`` over the mesh's ``batch``
axis: each device fits its own slice of the images, with no communication).  With
several processes (:mod:`jaxpose.distributed`) the mesh spans every process's
devices: each process passes its own images and gets back its own results, and
all of them run the same program, as JAX's multi-controller model asks.

Results on several devices are not bit-identical to one device's: the program of
several devices is compiled by XLA's SPMD pipeline, which fuses some arithmetic
differently from a one-device program.  On short searches they agree to float32
round-off (tested); over a full search the round-off can send the search along
another path, to another pose as well placed (docs/scaling.md).  Programs of 2
and 4 devices agreed exactly.
"""

from __future__ import annotations

import time

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding
from jax.sharding import PartitionSpec as P

from .errors import ConfigError
from .objective import Cloud
from .search import FitConfig, FitParams, FitResult, fit
from .skeleton import Skeleton

AXIS = "batch"


def local_devices(n: int | None = None) -> list:
    """This process's devices, the first ``n`` of them (all when ``None``)."""
    devices = jax.local_devices()
    if n is None:
        return devices
    if not 1 <= n <= len(devices):
        raise ConfigError(f"devices must lie within 1 .. {len(devices)} (this process's devices), got {n}")
    return devices[:n]


def device_mesh(devices_per_process: int | None = None, axis: str = AXIS) -> Mesh:
    """A one-axis mesh of every process's devices (the first ``devices_per_process``
    of each), ordered by process, so that each process's devices hold one contiguous
    slice of the batch."""
    n = len(local_devices(devices_per_process))
    by_process: dict[int, list] = {}
    for d in sorted(jax.devices(), key=lambda d: (d.process_index, d.id)):
        by_process.setdefault(d.process_index, []).append(d)
    devices = [d for p in sorted(by_process) for d in by_process[p][:n]]
    return Mesh(np.array(devices), (axis,))


_PROGRAMS: dict = {}


def _sharded(key, build, mesh: Mesh):
    """``build()``'s per-device function ``(replicated, batched) -> outputs`` as one
    program over ``mesh`` (``shard_map`` along its axis), cached by ``key`` and mesh."""
    if (key, mesh) not in _PROGRAMS:
        axis = mesh.axis_names[0]
        # check_vma=False: the search's scans start from constants (replicated) and carry
        # per-image values; every value here is per device, nothing is exchanged
        _PROGRAMS[key, mesh] = jax.jit(jax.shard_map(build(), mesh=mesh, in_specs=(P(), P(axis)),
                                                     out_specs=P(axis), check_vma=False))
    return _PROGRAMS[key, mesh]


def _fit_program(config: FitConfig, mesh: Mesh):
    """The batch's program for ``config``'s static part and the mesh (compiled by jit at
    its first call for each skeleton and shape).  ``config``'s traced settings are not
    read: the program takes them as ``params``, so one program serves every value."""
    def build():
        def local(replicated, batched):
            skeleton, params = replicated
            points, weights, key_data = batched
            one = lambda c, k: fit(c, skeleton, k, config, params)  # noqa: E731
            return jax.vmap(one)(Cloud(points, weights), jax.random.wrap_key_data(key_data))
        return local

    # the turns' count and window and the restarts are read here, not by the compiled searches (FitConfig.static)
    return _sharded(("fit", config.static(), config.turns, config.turn_window, config.restarts, config.restart_apart),
                    build, mesh)


def _run(program, mesh: Mesh, replicated, batched: list):
    """``program`` on this process's rows ``batched`` (NumPy, leading axis ``B``),
    padded to a whole number per device of the largest share over processes, and
    ``replicated`` (the same on every device); returns this process's ``B`` rows."""
    if len(mesh.axis_names) != 1:
        raise ConfigError(f"a mesh with one axis, got axes {mesh.axis_names}")
    B = len(batched[0])
    local = [d for d in mesh.devices.flat if d.process_index == jax.process_index()]
    n = padded_size(B, len(local))
    sharding = NamedSharding(mesh, P(mesh.axis_names[0]))
    args = [jax.make_array_from_process_local_data(sharding, _pad(np.ascontiguousarray(x), n)) for x in batched]
    out = program(jax.tree_util.tree_map(np.asarray, replicated), args)
    return jax.tree_util.tree_map(lambda x: _local_rows(x)[:B], out)


def _key_rows(keys, B: int) -> np.ndarray:
    """``(B, ...)`` raw key data from ``B`` keys or one key for all."""
    key_data = np.asarray(jax.random.key_data(keys))
    if key_data.ndim == 1:  # one key for every item
        key_data = np.broadcast_to(key_data, (B, *key_data.shape))
    if len(key_data) != B:
        raise ConfigError(f"{len(key_data)} keys for {B} inputs")
    return key_data


def _pad(x: np.ndarray, n: int) -> np.ndarray:
    """``x`` with its leading axis padded to ``n`` rows by copies of its first row (zeros if it has none)."""
    if len(x) == n:
        return x
    fill = np.repeat(x[:1], n - len(x), 0) if len(x) else np.zeros((n, *x.shape[1:]), x.dtype)
    return np.concatenate([x, fill])


def _local_rows(x: jax.Array) -> np.ndarray:
    """The rows of a batch-sharded global array held by this process, in order."""
    shards = sorted(x.addressable_shards, key=lambda s: s.index[0].start or 0)
    rows, seen = [], set()
    for s in shards:
        start = s.index[0].start or 0
        if start not in seen:  # a replicated copy on another device
            seen.add(start)
            rows.append(np.asarray(s.data))
    return np.concatenate(rows)


def padded_size(n_local: int, devices: int) -> int:
    """Images per process after padding: the largest share over processes, rounded
    up to a whole number per device (every process runs the same program)."""
    if jax.process_count() > 1:
        from jax.experimental import multihost_utils

        n_local = int(np.max(multihost_utils.process_allgather(np.int32(n_local))))
    return max(1, -(-n_local // devices)) * devices


def fit_batch(clouds: Cloud, skeleton: Skeleton, keys, config: FitConfig = FitConfig(),
              mesh: Mesh | None = None, params: FitParams | None = None) -> FitResult:
    """Fit ``skeleton`` to a batch of clouds, sharded over the devices of ``mesh``.

    Args:
      clouds: a :class:`Cloud` with a leading batch axis ``(B, N, 3)``, ``(B, N)``:
        this process's images (every image of the batch with one process).
      skeleton: the model.
      keys: ``(B,)`` random keys (``jax.random.split``), or one key for every image.
      config: the search's settings (static); ``params``: the traced ones
        (default ``config.params()``), the same for every image.
      mesh: a one-axis mesh (default :func:`device_mesh`: every device of every
        process).  The batch is padded to a whole number of images per device (copies
        of an image, discarded) and split along the mesh's axis.

    Returns:
      A :class:`FitResult` whose leaves have the batch axis ``B`` first, as NumPy
      arrays on the host, in the order of ``clouds``; ``wall_time`` holds the
      batch's wall time (compilation included on the first call of a shape).

    With several processes every process must call this (with its own ``B``, which
    may differ and may be 0) with the same config, mesh and cloud size.
    """
    t0 = time.perf_counter()
    config = config.validate().for_skeleton(skeleton)
    params = config.params() if params is None else params
    mesh = device_mesh() if mesh is None else mesh
    points = np.asarray(clouds.points, np.float32)
    weights = np.asarray(clouds.weights, np.float32)
    if points.ndim != 3 or points.shape[2] != 3 or weights.shape != points.shape[:2]:
        raise ConfigError(f"fit_batch: clouds of shape (B, N, 3) and weights (B, N), got {points.shape} "
                          f"and {weights.shape}")
    res = _run(_fit_program(config, mesh), mesh, (skeleton, params), [points, weights, _key_rows(keys, len(points))])
    return res._replace(wall_time=np.full(len(points), time.perf_counter() - t0, np.float32))


def track_batch(clouds: Cloud, skeleton: Skeleton, keys, config=None, mesh: Mesh | None = None,
                chunk: int | None = None, progress=None):
    """Track several sequences at once, sharded over the devices of ``mesh`` as
    :func:`fit_batch` shards images: :func:`jaxpose.tracking.track_batched` on each
    device's sequences.

    Args:
      clouds: ``points (S, T, N, 3)``, ``weights (S, T, N)``: this process's ``S``
        sequences of ``T`` frames each.
      skeleton: the model.
      keys: ``(S,)`` random keys, or one key for every sequence.
      config: a :class:`~jaxpose.tracking.TrackConfig` (default ``TrackConfig()``).
      mesh: as for :func:`fit_batch`.
      chunk: frames per call of the compiled program (default: all of them in one), as
        :func:`track_batch_chunks`.
      progress: ``progress(frames done, T)``, called after each chunk.

    Returns:
      The :class:`~jaxpose.tracking.step.TrackFrame` of every frame, leaves ``(S, T, ...)``
      as NumPy arrays, in the order of ``clouds``.
    """
    parts = []
    for t0, frames in track_batch_chunks(clouds, skeleton, keys, config, mesh, chunk):
        parts.append(frames)
        if progress is not None:
            progress(t0 + frames.mode.shape[1], np.shape(clouds.points)[1])
    return jax.tree_util.tree_map(lambda *xs: np.concatenate(xs, 1), *parts)


def track_batch_chunks(clouds: Cloud, skeleton: Skeleton, keys, config=None, mesh: Mesh | None = None,
                       chunk: int | None = None):
    """:func:`track_batch` a chunk of frames at a time: yields ``(t0, frames)``, the
    :class:`~jaxpose.tracking.step.TrackFrame` of frames ``t0 .. t0 + n`` of every
    sequence (leaves ``(S, n, ...)``, NumPy), as soon as they are computed, so that a
    caller can write them and report progress.  One compiled program
    (:func:`~jaxpose.tracking.track_batched_from` on ``chunk`` frames, default ``T``)
    runs every chunk; the sequences' states carry from one call to the next, and the
    last chunk is padded with empty frames (lost, never returned)."""
    from .tracking import TrackConfig, initial_state, track_batched_from

    config = (TrackConfig() if config is None else config).validate().for_skeleton(skeleton)
    mesh = device_mesh() if mesh is None else mesh
    points = np.asarray(clouds.points, np.float32)
    weights = np.asarray(clouds.weights, np.float32)
    if points.ndim != 4 or points.shape[3] != 3 or weights.shape != points.shape[:3]:
        raise ConfigError(f"track_batch: sequences of shape (S, T, N, 3) and weights (S, T, N), got "
                          f"{points.shape} and {weights.shape}")
    if chunk is not None and (isinstance(chunk, bool) or not isinstance(chunk, int) or chunk < 1):
        raise ConfigError(f"track_batch: chunk must be a whole number >= 1, got {chunk!r}")
    key_rows, T = _key_rows(keys, len(points)), points.shape[1]
    if T == 0:
        raise ConfigError("track_batch: sequences of at least one frame, got T = 0")
    chunk = T if chunk is None else min(chunk, T)

    def build():
        def local(skel, batched):  # a state's key travels as its raw data
            pts, w, *leaves = batched
            state, frames = track_batched_from(_unpack_state(leaves), Cloud(pts, w), skel, config)
            return _pack_state(state), frames
        return local

    program = _sharded(("track", config), build, mesh)

    def chunks():  # the checks above run at the call, the frames as they are asked for
        start = jax.vmap(lambda k: initial_state(skeleton, k))(jax.random.wrap_key_data(key_rows))
        state = [np.asarray(x) for x in _pack_state(start)]
        for t0 in range(0, T, chunk):
            n = min(chunk, T - t0)
            pad = ((0, 0), (0, chunk - n))  # empty frames: lost, and never returned
            pts = np.pad(points[:, t0:t0 + n], pad + ((0, 0), (0, 0)))
            w = np.pad(weights[:, t0:t0 + n], pad + ((0, 0),))
            state, frames = _run(program, mesh, skeleton, [pts, w, *state])
            yield t0, jax.tree_util.tree_map(lambda x: x[:, :n], frames)  # noqa: B023 - used at once

    return chunks()


def _pack_state(state) -> tuple:
    """A :class:`~jaxpose.tracking.TrackState`'s leaves, its key as raw data (what a sharded program passes)."""
    return (*state[:5], jax.random.key_data(state.key), state.last_global)


def _unpack_state(leaves):
    """The :class:`~jaxpose.tracking.TrackState` of :func:`_pack_state`'s leaves."""
    from .tracking import TrackState

    return TrackState(*leaves[:5], jax.random.wrap_key_data(leaves[5]), leaves[6])


def _island_shardings(mesh: Mesh, state, islands: int):
    """Shardings of a :class:`~jaxpose.search.state.SearchState`: the island axis of
    every per-island field split over the mesh, the shared fields replicated."""
    from .search.state import SHARED

    split, whole = NamedSharding(mesh, P(mesh.axis_names[0])), NamedSharding(mesh, P())
    per_leaf = lambda x: split if x.ndim and x.shape[0] == islands else whole  # noqa: E731
    return state._replace(**{name: jax.tree_util.tree_map(
        (lambda x: whole) if name in SHARED else per_leaf, getattr(state, name)) for name in state._fields})


_ISLAND_PROGRAMS: dict = {}


def _island_program(config: FitConfig, mesh: Mesh):
    from .search.loop import search_epoch, search_finish, search_init

    key = (config.static(), mesh)
    if key in _ISLAND_PROGRAMS:
        return _ISLAND_PROGRAMS[key]
    static = config.static()

    def sharded_fit(cloud, skeleton, rng, params):
        # fit()'s steps (jaxpose/search/loop.py) with the state's island axis split over
        # the devices between epochs; XLA's SPMD partitioner keeps it split inside them
        # and inserts the exchange that successive halving needs
        st = search_init(cloud, skeleton, rng, static, params)
        shardings = _island_shardings(mesh, st, static.islands)
        constrain = lambda s: jax.lax.with_sharding_constraint(s, shardings)  # noqa: E731
        st, hists = constrain(st), []
        E, n_full = static.epoch, static.generations // static.epoch
        def epoch(s, _):
            s, h = search_epoch(skeleton, static, s, E)
            return constrain(s), h

        if n_full:
            st, h = jax.lax.scan(epoch, st, None, length=n_full)
            hists.append(h.reshape(-1))
        if len(static.epoch_lengths) > n_full:
            st, h = search_epoch(skeleton, static, st, static.epoch_lengths[-1])
            st = constrain(st)
            hists.append(h)
        return search_finish(cloud, skeleton, static, st, jax.numpy.concatenate(hists))

    _ISLAND_PROGRAMS[key] = jax.jit(sharded_fit)
    return _ISLAND_PROGRAMS[key]


def fit_islands(cloud: Cloud, skeleton: Skeleton, key, config: FitConfig = FitConfig(),
                mesh: Mesh | None = None, params: FitParams | None = None, progress=None) -> FitResult:
    """One fit with its islands split over the devices of ``mesh`` (default: this
    process's devices); the same searches as :func:`~jaxpose.search.fit` (a portfolio's
    one after another).

    Islands are independent until successive halving, which copies the better half's
    populations over the worse half's; XLA then exchanges them between devices.
    ``config.islands`` must be a multiple of the mesh's size.  ``progress(generations,
    best_cost, evaluations)`` is called after each search (one compiled program runs a
    whole search).  Returns the :class:`FitResult` (JAX arrays, replicated)."""
    config = config.validate().for_skeleton(skeleton)
    params = config.params() if params is None else params
    mesh = Mesh(np.array(local_devices()), (AXIS,)) if mesh is None else mesh
    if len(mesh.axis_names) != 1 or config.islands % mesh.devices.size:
        raise ConfigError(f"{config.islands} islands do not split evenly over {mesh.devices.size} devices: "
                          "the islands must be a multiple of the devices")
    from .search.loop import cheapest, run_searches

    cloud = Cloud(np.asarray(cloud.points, np.float32), np.asarray(cloud.weights, np.float32))
    host = lambda tree: jax.tree_util.tree_map(np.asarray, tree)  # noqa: E731
    program = _island_program(config, mesh)
    done = {"generations": 0, "best": float("inf"), "evaluations": 0}

    def search(k, p):
        r = program(cloud, host(skeleton), k, host(p))
        if progress is not None:
            done["generations"] += config.generations
            done["best"] = min(done["best"], float(r.cost))
            done["evaluations"] += int(r.objective_evaluations) + int(r.gradient_evaluations)  # as Fitter.run
            progress(done["generations"], done["best"], done["evaluations"])
        return r

    # the searches one after another, as Fitter.run runs them
    results = run_searches(skeleton, config, params, key, search, cloud)
    return results[0] if len(results) == 1 else cheapest(results)


__all__ = ["AXIS", "device_mesh", "fit_batch", "fit_islands", "local_devices", "padded_size", "track_batch",
           "track_batch_chunks"]
