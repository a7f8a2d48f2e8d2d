"""``jaxpose track --sequences``: several sequences tracked at once, sharded over the devices.

Every sequence (a folder of frames, or one ``(T, H, W)`` ``.npy`` stack) is read as
``jaxpose track`` reads its ``INPUT``; then all of them go through
:func:`jaxpose.parallel.track_batch`: :func:`jaxpose.tracking.track_batched` (one
``lax.scan`` over the frames of a device's sequences), one compiled program
sharded over the first ``--devices`` devices, ``CHUNK`` frames a call
(:func:`jaxpose.parallel.track_batch_chunks`).  A shorter sequence is padded with
empty frames (weight 0: the tracker calls them lost), and only its real frames
are written.  Each sequence's results go to ``DIR/<sequence stem>/``, the files
``jaxpose track`` writes for one sequence; a chunk's frames are written as soon
as it is computed, so Ctrl-C keeps them (and their ``track.json``, marked
``interrupted``).

With several processes (:mod:`jaxpose.distributed`) each process tracks and writes
every P-th sequence, as ``fit`` shares its inputs; ``--resume`` skips the sequences
already written.

A scan reports no time per frame: each frame's ``wall_seconds`` is ``null``; its
``timing.batch`` records the batch and the chunk's call that computed it, and
``summary.batch`` the batch's wall time and compilation time (docs/result_json.md).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import os
import time

import numpy as np

from ..errors import ConfigError
from .progress import FrameBar, check_output_path

# summary()'s times of single frames, which a scan does not measure (null here)
CHUNK = 10  # frames per call of the batch's program: the progress bar moves every CHUNK frames
FRAME_TIMES = ("fps", "median_frame_seconds", "p90_frame_seconds", "first_frame_seconds", "global_median_seconds")
COMPILE_EVENTS = ("/jax/core/compile/jaxpr_trace_duration", "/jax/core/compile/jaxpr_to_mlir_module_duration",
                  "/jax/core/compile/backend_compile_duration")


@dataclasses.dataclass
class Sequence:
    """One ``--sequences`` argument: its frames and where its results go."""

    source: str  # as given
    name: str  # DIR/<name>/
    frames: list  # track.Frame
    stack: np.ndarray | None  # the memory-mapped (T, H, W) stack, or None for a folder


def check_combinations(args) -> None:
    """:class:`ConfigError` for options that do not go with ``--sequences`` (or need it)."""
    if args.sequences is None:
        if not args.depth:
            raise ConfigError("give the frames of one sequence (INPUT ...) or several sequences (--sequences SEQ ...)")
        if args.devices is not None:
            raise ConfigError("--devices works with --sequences (one sequence is tracked frame by frame, "
                              "on one device)")
        if args.resume:
            raise ConfigError("--resume works with --sequences (it skips the sequences already written)")
        return
    if args.depth:
        raise ConfigError(f"INPUT ({args.depth[0]}) and --sequences exclude each other: give each sequence "
                          "(a folder or a .npy stack) to --sequences")
    if args.video:
        raise ConfigError("--video works with one sequence (INPUT ...), not with --sequences")


def check_devices(devices: int | None) -> None:
    """``--devices`` within this machine's devices (and the run joined, with several processes)."""
    import jax

    from .. import distributed

    distributed.check()
    if devices is not None and devices < 1:
        raise ConfigError(f"--devices must be >= 1, got {devices}")
    if devices is not None and devices > jax.local_device_count():
        raise ConfigError(f"--devices must lie within 1 .. {jax.local_device_count()} (this machine's "
                          f"{jax.devices()[0].platform.upper()} devices), got {devices}")


def finished(folder: str) -> bool:
    """Whether a sequence's ``track.json`` is written and was not interrupted (``--resume``)."""
    import json

    try:
        with open(os.path.join(folder, "track.json")) as f:
            doc = json.load(f)
        return isinstance(doc, dict) and not doc.get("summary", {}).get("interrupted", False)
    except (OSError, ValueError, AttributeError):
        return False


def expand_sequences(paths: list[str], out_dir: str, depth_scale=None) -> list[Sequence]:
    """Each ``--sequences`` path as its frames; :class:`ConfigError` or
    :class:`~jaxpose.errors.DepthError` for a path that is neither a folder nor a stack,
    and for two sequences that would write the same folder."""
    from .track import _load_stack, expand_inputs

    seqs, seen = [], {}
    for path in paths:
        if not os.path.exists(path):
            raise ConfigError(f"--sequences {path}: no such folder or file")
        frames = expand_inputs([path])
        folder = os.path.isdir(path)
        if not folder and frames[0].index is None:
            raise ConfigError(f"--sequences {path}: a sequence is a folder of frames or one (T, H, W) .npy stack")
        name = os.path.basename(os.path.abspath(path)) if folder else os.path.splitext(os.path.basename(path))[0]
        if name.casefold() in seen:
            raise ConfigError(f"sequences {seen[name.casefold()]} and {path} would both write {name}/ in --out-dir")
        seen[name.casefold()] = path
        if any(f.name.casefold() == "track" for f in frames):
            raise ConfigError(f"--sequences {path}: a frame named track.* would write track.json, the summary; "
                              "rename it")
        target = os.path.join(out_dir, name)
        if os.path.exists(target) and not os.path.isdir(target):
            raise ConfigError(f"--out-dir {out_dir}: {name} (sequence {path}) exists and is not a folder")
        if os.path.isdir(target):
            check_output_path(os.path.join(target, "track.json"), "--out-dir")
        stack = _load_stack(frames[0].source, depth_scale) if frames[0].index is not None else None
        seqs.append(Sequence(path, name, frames, stack))
    return seqs


@contextlib.contextmanager
def compile_seconds():
    """``[seconds]``: the time JAX spends tracing, lowering and compiling programs (or loading
    them from the compilation cache) inside the block."""
    import jax

    total = [0.0]

    def listener(event, duration, **kwargs):
        if event in COMPILE_EVENTS:
            total[0] += duration

    jax.monitoring.register_event_duration_secs_listener(listener)
    try:
        yield total
    finally:
        jax.monitoring.unregister_event_duration_listener(listener)


def batch_summary(entries: list[dict], batch: dict, interrupted: bool = False) -> dict:
    """track.json's ``summary`` of one sequence of the batch: the counts of :func:`summary`,
    no time per frame (null), and the batch's times under ``batch``."""
    from .track import summary

    # the counts; the times are set to null below
    s = summary([{**e, "wall_seconds": 0.0} for e in entries], interrupted)
    s.update(dict.fromkeys(FRAME_TIMES))
    s["batch"] = batch
    return s


def _count(n: int, what: str) -> str:
    return f"{n} {what}{'' if n == 1 else 's'}"


def run_sequences(args: argparse.Namespace) -> int:
    import jax

    from .. import distributed
    from ..io.atomic import write_json
    from ..io.fit_result import file_sha256
    from ..objective import Cloud
    from ..parallel import device_mesh, track_batch_chunks
    from ..pipeline import load_fit_skeleton
    from ..tracking import MODES
    from .fit import input_options
    from .fit_batch import agree, largest
    from .robot_options import check_search_options, robot_record
    from .track import FrameReader, _empty_cloud, _input_record, frame_document, track_config_from_args

    config = track_config_from_args(args)
    check_search_options(args)
    check_devices(args.devices)
    if not os.path.isdir(args.out_dir):
        raise ConfigError(f"--out-dir {args.out_dir}: not a directory")
    check_output_path(os.path.join(args.out_dir, "track.json"), "--out-dir")  # DIR is writable
    every_seq = expand_sequences(args.sequences, args.out_dir, args.depth_scale)
    every = [f.source for s in every_seq for f in (s.frames[:1] if s.stack is not None else s.frames)]  # a stack once
    options = input_options(argparse.Namespace(**{**vars(args), "depth": every}))
    skel, skel_file = load_fit_skeleton(args.skeleton, args.search_lengths, args.max_capsules, args.search_scale)
    robot = robot_record(args, skel_file)
    config = config.validate().for_skeleton(skel)
    P = jax.process_count()
    who = f"process {jax.process_index()} of {P}: " if P > 1 else ""
    mine = distributed.share(every_seq)  # every P-th sequence, as fit shares its inputs
    seqs = [s for s in mine if not (args.resume and finished(os.path.join(args.out_dir, s.name)))]
    if not args.quiet and len(seqs) < len(mine):
        print(f"{who}{len(mine) - len(seqs)} of {len(mine)} sequences already written, skipped", flush=True)
    ok = False
    try:  # every frame of every sequence read and checked before the search
        readers = [FrameReader(options, s.stack) for s in seqs]
        observed = [[r.read(f)[1:] for f in s.frames] for r, s in zip(readers, seqs)]
        ok = True
    finally:
        if not ok and P > 1:  # the others learn it before they wait for this process's programs
            agree(False, "reading the sequences")
    agree(True, "reading the sequences")
    T = largest(max((len(s.frames) for s in seqs), default=0))  # every process scans as many frames
    if T == 0:
        if not args.quiet:
            print(f"{who}every sequence is already written -> {args.out_dir}", flush=True)
        return 0
    empty = _empty_cloud(options.max_points)
    padded = [[c for _, c, _ in obs] + [empty] * (T - len(obs)) for obs in observed]
    clouds = Cloud(np.asarray([[np.asarray(c.points, np.float32) for c in p] for p in padded], np.float32)
                   .reshape(len(seqs), T, options.max_points, 3),
                   np.asarray([[np.asarray(c.weights, np.float32) for c in p] for p in padded], np.float32)
                   .reshape(len(seqs), T, options.max_points))
    mesh = device_mesh(args.devices)
    devices = int(mesh.devices.size)
    platform = mesh.devices.flat[0].platform.upper()
    if not args.quiet and seqs:
        lengths = sorted({len(s.frames) for s in seqs})
        span = f"{T} frames each" if lengths == [T] else f"{lengths[0]} to {lengths[-1]} frames (padded to {T})"
        print(f"{who}{_count(len(seqs), 'sequence')} of {span} on {devices} {platform} device(s)"
              f"{f' of {P} processes' if P > 1 else ''}: compiling and running one program", flush=True)
    bar = FrameBar(T, args.quiet)
    run = {"sequences": len(seqs), "devices": devices, "processes": P, "frames": T}
    stack_sha = [file_sha256(s.frames[0].source) if s.stack is not None else None for s in seqs]
    entries: list[list[dict]] = [[] for _ in seqs]
    chunks = track_batch_chunks(clouds, skel, jax.random.key(args.seed), config, mesh, CHUNK)
    compiled, interrupted, t0 = 0.0, True, time.perf_counter()
    try:
        while True:
            t_call = time.perf_counter()
            with compile_seconds() as seconds:
                item = next(chunks, None)
            compiled += seconds[0]
            if item is None:
                break
            c0, frames = item
            n = int(frames.mode.shape[1])
            timing = {"wall_seconds": None, "batch": {**run, "chunk_frames": [c0, c0 + n],
                                                      "chunk_seconds": time.perf_counter() - t_call}}
            # each chunk's frames written at once: Ctrl-C later keeps them (as jaxpose track does)
            for i, (s, obs) in enumerate(zip(seqs, observed)):
                folder = os.path.join(args.out_dir, s.name)
                os.makedirs(folder, exist_ok=True)
                for t in range(c0, min(c0 + n, len(s.frames))):
                    f, (k, cloud, note) = s.frames[t], obs[t]
                    result = jax.tree_util.tree_map(lambda x: x[i, t - c0], frames.result)  # noqa: B023
                    mode = MODES[int(frames.mode[i, t - c0])]
                    record = _input_record(f, options, k, cloud, stack_sha[i])
                    doc = frame_document(skel, skel_file, result, mode, config, args.seed, record, t, cloud, note)
                    doc["skeleton"].update(robot)
                    doc["timing"] = timing
                    write_json(os.path.join(folder, f.name + ".json"), doc)
                    entries[i].append({"input": f.source if f.index is None else f.name,  # the path as given
                                       "frame": t, "mode": mode, "cost": doc["cost"], "wall_seconds": None})
            rate = (c0 + n) * len(seqs) / max(time.perf_counter() - t0, 1e-9)
            bar.show(f"frame {c0 + n}/{T} of {_count(len(seqs), 'sequence')}  {rate:.1f} frames/s "
                     "(with compilation)", c0 + n)
        interrupted = False
    finally:
        bar.close()
        wall = time.perf_counter() - t0
        batch = {**run, "wall_seconds": wall, "compile_seconds": compiled}
        for s, ents in zip(seqs, entries):  # also after Ctrl-C: the frames written so far and their summary
            if ents:
                summ = batch_summary(ents, batch, interrupted)
                write_json(os.path.join(args.out_dir, s.name, "track.json"),
                           {"skeleton": skel.name, "frames": ents, "summary": summ})
                if not args.quiet and not interrupted:
                    print(f"{who}{s.source}: {summ['frames']} frames, {summ['reinitialisations']} re-initialisations, "
                          f"{summ['lost_frames']} lost -> {os.path.join(args.out_dir, s.name)}", flush=True)
    if not args.quiet:
        frames_done = sum(len(s.frames) for s in seqs)
        print(f"{who}{skel.name}: {_count(len(seqs), 'sequence')}, {frames_done} frames on {devices} "
              f"{platform} device(s) in {wall:.1f} s ({compiled:.1f} s compiling) -> {args.out_dir}", flush=True)
    return 0


__all__ = ["run_sequences", "check_combinations", "expand_sequences"]
