"""``jaxpose track``: fit a depth stream frame after frame, each warm-started from the last."""

from __future__ import annotations

import argparse
import dataclasses
import os

import numpy as np

from ..errors import ConfigError, DepthError
from ..objective import ObjectiveConfig
from ..search import FitConfig
from .progress import FrameBar, check_output_path
from .robot_options import add_search_options, check_search_options, robot_record

FRAME_EXTENSIONS = (".png", ".npy", ".ply", ".pcd", ".xyz")  # the files a folder input contributes
VIDEO_EXTENSIONS = (".gif", ".mp4")


def register(sub) -> None:
    from ..tracking import TrackConfig

    t = TrackConfig()
    p = sub.add_parser("track", help="track a skeleton through a sequence of depth images or point clouds",
                       description="Track a skeleton through depth images or point clouds in order: the first "
                                   "frame (and any frame after the subject was lost) by the global search of "
                                   "'jaxpose fit', every other frame from the last pose. Writes DIR/<input>.json "
                                   "per frame and DIR/track.json; with --sequences, DIR/<sequence>/ each.")
    p.add_argument("depth", metavar="INPUT", nargs="*",
                   help="depth images (16-bit PNG in millimetres, 2-D .npy in metres) or point clouds (.ply, "
                        ".pcd, .xyz, (N, 3) .npy) in order; or one folder (its such files in name order); or "
                        "one (T, H, W) .npy stack of depth frames in metres (or --sequences instead)")
    p.add_argument("--sequences", nargs="+", metavar="SEQ",
                   help="several sequences at once, each a folder or a (T, H, W) .npy stack read as INPUT is: "
                        "tracked together by one compiled program sharded over the devices (shorter ones padded "
                        "with empty frames), each written to DIR/<SEQ stem>/ as one sequence's files")
    p.add_argument("--devices", type=int, metavar="N",
                   help="with --sequences: shard the sequences over the first N devices of this machine "
                        "(default: every device; with several processes, N of each)")
    p.add_argument("--resume", action="store_true",
                   help="with --sequences: skip the sequences whose track.json is already written (and not "
                        "interrupted)")
    p.add_argument("--skeleton", required=True, help="skeleton file (.toml/.json/.urdf/.xml) or a shipped name")
    p.add_argument("--out-dir", required=True, metavar="DIR",
                   help="write DIR/<input name>.json per frame (a stack: DIR/<stem>_<frame:05d>.json) and "
                        "DIR/track.json")
    p.add_argument("--video", metavar="FILE", help="the overlays of every frame as a video (.gif; .mp4 needs "
                                                    "imageio-ffmpeg)")
    p.add_argument("--intrinsics", help="depth images: 'kinect', 'fx,fy,cx,cy' or a JSON file (default kinect)")
    p.add_argument("--depth-scale", type=float, help="depth images: metres per PNG unit (default 0.001)")
    p.add_argument("--cloud-scale", type=float,
                   help="point clouds: metres per unit of the file's coordinates (default 1)")
    p.add_argument("--viewpoint", metavar="TX,TY,TZ,QW,QX,QY,QZ",
                   help="point clouds: the sensor's pose in the cloud's frame (default: the file's, else identity)")
    p.add_argument("--near", type=float, default=0.3, help="nearest depth kept, metres (default 0.3)")
    p.add_argument("--far", type=float, default=8.0, help="farthest depth kept, metres (default 8)")
    p.add_argument("--background", help="depth images: background depth image to subtract (same size)")
    p.add_argument("--remove-planes", type=int, default=0, metavar="N",
                   help="drop the points of up to N largest planes in every frame (default 0)")
    p.add_argument("--max-points", type=int, default=1024, help="points sampled per frame (default 1024)")
    p.add_argument("--scale", type=float, default=None, metavar="S",
                   help="the subject's global scale when known (default: searched; 1 for a robot file)")
    add_search_options(p)
    g = p.add_argument_group("the global search (first frame, recovery, rechecks); as in 'jaxpose fit'")
    g.add_argument("--algorithm", default="ga", help="ga (default), hc, cma_es or another evosax strategy")
    g.add_argument("--population", type=int, default=FitConfig.population)
    g.add_argument("--generations", type=int, default=FitConfig.generations,
                   help="generations (default: 4 per searched gene, within 100..300)")
    g.add_argument("--islands", type=int, default=FitConfig.islands)
    g.add_argument("--coarse-points", type=int, default=FitConfig.coarse_points)
    g.add_argument("--tie-lengths", action="store_true", help="one length for alike links")
    g.add_argument("--no-refine", action="store_true", help="no gradient refinement in the global search")
    g.add_argument("--one-search", action="store_true",
                   help="the global search: the staged search alone, not the portfolio (the turns still run)")
    g.add_argument("--turns", type=int, default=FitConfig.turns, metavar="N",
                   help=f"turn searches after the global search's portfolio (0-3; default {FitConfig.turns})")
    g.add_argument("--restarts", type=int, default=FitConfig.restarts, metavar="K",
                   help=f"the global search run K times, the cheapest answer kept (default {FitConfig.restarts})")
    g.add_argument("--restart-apart", type=float, default=FitConfig.restart_apart, metavar="F",
                   help="with --restarts: a restart only when the answers so far lie further apart than F times "
                        f"the cloud's spread (default {FitConfig.restart_apart:g})")
    g.add_argument("--limb-sweep", type=int, default=FitConfig.limb_sweep, metavar="N",
                   help=f"the limb sweep: N generations a limb (0: off; default {FitConfig.limb_sweep})")
    g.add_argument("--pivot-sweep", type=int, default=FitConfig.pivot_sweep, metavar="N",
                   help=f"the pivot sweep: N generations a pivot (0: off; default {FitConfig.pivot_sweep})")
    g.add_argument("--sigma-factor", type=float, default=ObjectiveConfig.sigma_factor)
    g.add_argument("--free-space-weight", type=float, default=ObjectiveConfig.free_space_weight)
    g.add_argument("--collision-weight", type=float, default=ObjectiveConfig.collision_weight)
    g.add_argument("--max-range", type=float, metavar="METRES",
                   help="the sensor measures nothing beyond this depth (as fit's --max-range)")
    g.add_argument("--seed", type=int, default=0)
    k = p.add_argument_group("tracking (docs/tracking.md)")
    k.add_argument("--track-population", type=int, default=t.population,
                   help=f"individuals per generation around the prediction (default {t.population})")
    k.add_argument("--track-generations", type=int, default=t.generations,
                   help=f"generations per tracked frame (default {t.generations})")
    k.add_argument("--track-refine-steps", type=int, default=t.refine_steps,
                   help=f"Adam steps that finish a tracked frame (default {t.refine_steps})")
    k.add_argument("--track-sweep", type=int, default=t.sweep_limbs,
                   help=f"limbs searched anew per tracked frame, in turn (0: off; default {t.sweep_limbs})")
    k.add_argument("--track-recheck", type=int, default=t.recheck_every, metavar="N",
                   help="N frames after the global search last ran, run it again beside the local search and keep "
                        "the cheaper fit (a fit wrong from the start gets another chance; each costs a global fit; "
                        f"0: never, default {t.recheck_every})")
    k.add_argument("--track-recheck-margin", type=float, default=t.recheck_margin, metavar="M",
                   help="a recheck's global fit replaces the tracked one only when cheaper by this fraction "
                        f"(default {t.recheck_margin})")
    k.add_argument("--track-length-window", type=float, default=t.length_window, metavar="F",
                   help="a tracked frame's link lengths stay within this factor of the last frame's (1: held at "
                        f"the global fit's; 0: the skeleton's ranges; default {t.length_window:g})")
    k.add_argument("--min-points", type=int, default=t.min_points,
                   help=f"a frame with fewer points is lost: the subject is out of view (default {t.min_points})")
    k.add_argument("--loss-ratio", type=float, default=t.loss_ratio,
                   help="a tracked frame whose cost exceeds this times the recent cost runs the global search "
                        f"(default {t.loss_ratio})")
    p.add_argument("--quiet", action="store_true", help="no progress bar and no summary line")
    p.set_defaults(func=run, hypotheses=1, time_budget=None, plot=None, plots=False, out=None)


TRACK_FLAGS = {"population": "--track-population", "generations": "--track-generations",
               "refine_steps": "--track-refine-steps", "sweep_limbs": "--track-sweep", "min_points": "--min-points",
               "recheck_every": "--track-recheck", "recheck_margin": "--track-recheck-margin",
               "loss_ratio": "--loss-ratio", "length_window": "--track-length-window"}


def track_config_from_args(args):
    """The tracking settings; :class:`ConfigError` names the offending option."""
    from ..tracking import TrackConfig
    from .fit import config_from_args

    fit = config_from_args(args)
    cfg = TrackConfig(fit=fit, population=args.track_population, generations=args.track_generations,
                      refine_steps=args.track_refine_steps, sweep_limbs=args.track_sweep,
                      recheck_every=args.track_recheck, recheck_margin=args.track_recheck_margin,
                      min_points=args.min_points, loss_ratio=args.loss_ratio, length_window=args.track_length_window)
    try:
        return cfg.validate()
    except ConfigError as e:
        msg = str(e)
        name = msg.split(" ", 1)[0]
        raise ConfigError(TRACK_FLAGS.get(name, name) + " " + msg.split(" ", 1)[1]) from None


@dataclasses.dataclass
class Frame:
    """One input frame: where it comes from and what the outputs are called."""

    source: str  # the file (or the stack)
    index: int | None  # the frame in a stack, None for a file
    name: str  # its output stem
    cloud_file: bool


def expand_inputs(inputs: list[str]) -> list[Frame]:
    """Files, one folder, or one (T, H, W) .npy stack -> the frames in order; :class:`ConfigError`
    or :class:`DepthError` for an input that is none of these."""
    from ..io.cloud_file import is_cloud_file
    from ..io.depth_file import npy_header

    if len(inputs) == 1 and os.path.isdir(inputs[0]):
        folder = inputs[0]
        files = sorted(f for f in os.listdir(folder) if os.path.splitext(f)[1].lower() in FRAME_EXTENSIONS
                       and not f.startswith("."))
        if not files:
            raise DepthError(f"{folder}: the folder holds no depth image or point cloud "
                             f"({', '.join(FRAME_EXTENSIONS)})")
        inputs = [os.path.join(folder, f) for f in files]
    for path in inputs:
        if os.path.isdir(path):
            raise DepthError(f"{path}: is a directory; give one folder alone, or files")
    if len(inputs) == 1 and inputs[0].lower().endswith(".npy") and os.path.isfile(inputs[0]):
        try:
            shape, _ = npy_header(inputs[0])
        except (ValueError, SyntaxError):
            shape = None
        if shape is not None and len(shape) == 3 and shape[-1] != 3:
            stem = os.path.splitext(os.path.basename(inputs[0]))[0]
            if shape[0] < 1:
                raise DepthError(f"{inputs[0]}: the stack holds no frame (shape {tuple(shape)})")
            return [Frame(inputs[0], t, f"{stem}_{t:05d}", False) for t in range(shape[0])]
    frames, seen = [], {}
    for path in inputs:
        stem = os.path.splitext(os.path.basename(path))[0]
        if stem.casefold() in seen:
            raise ConfigError(f"inputs {seen[stem.casefold()]} and {path} would both write {stem}.json in --out-dir")
        seen[stem.casefold()] = path
        frames.append(Frame(path, None, stem, is_cloud_file(path)))
    return frames


def _empty_cloud(n: int):
    from ..objective import Cloud

    return Cloud(np.zeros((n, 3), np.float32), np.zeros(n, np.float32))


class FrameReader:
    """Reads frames into clouds.  A file that cannot be read is bad input (an error); a frame
    that holds too few of the subject's points is an empty cloud (the tracker calls it lost)."""

    def __init__(self, options, stack: np.ndarray | None = None):
        from ..io.depth_file import read_depth

        self.options = options
        self.stack = stack
        self.background = None
        if options.background:
            try:
                self.background, _ = read_depth(options.background, options.depth_scale)
            except DepthError as e:
                raise DepthError(f"background image {e}") from None

    def depth_cloud(self, depth: np.ndarray, source: str):
        """``(depth, intrinsics, cloud, note)``: ``note`` says why the cloud is empty (None when it is not)."""
        from ..camera import depth_to_cloud
        from ..io.depth_file import parse_intrinsics

        o = self.options
        k = parse_intrinsics(o.intrinsics, depth.shape, image=source)
        if self.background is not None and self.background.shape != depth.shape:
            (bh, bw), (h, w) = self.background.shape, depth.shape
            raise DepthError(f"background image {o.background}: is {bw}x{bh}, but the depth image {source} "
                             f"is {w}x{h}")
        try:
            cloud = depth_to_cloud(depth, k, o.near, o.far, self.background, o.max_points, o.sample_seed,
                                   min_points=0, background_tolerance=o.background_tolerance, source=source,
                                   remove_planes=o.remove_planes, plane_tolerance=o.plane_tolerance)
            return depth, k, cloud, None
        except DepthError as e:  # nothing of the subject in this frame: the tracker reports it lost
            return depth, k, _empty_cloud(o.max_points), str(e)

    def read(self, frame: Frame):
        from ..io.depth_file import read_depth

        o = self.options
        if frame.index is not None:
            depth = np.asarray(self.stack[frame.index], np.float32).copy()
            with np.errstate(invalid="ignore"):
                depth[~np.isfinite(depth) | (depth <= 0)] = np.nan
            return self.depth_cloud(depth, f"{frame.source} frame {frame.index}")
        if frame.cloud_file:
            from ..camera import cloud_view, sensor_points_to_cloud
            from ..io.cloud_file import load_points, parse_viewpoint, to_sensor_frame

            pf = load_points(frame.source)
            vp = parse_viewpoint(o.viewpoint) if o.viewpoint is not None else pf.viewpoint
            pts = to_sensor_frame(pf.points, vp) * np.float32(o.cloud_scale)
            try:
                cloud, kept = sensor_points_to_cloud(pts, o.near, o.far, o.max_points, o.sample_seed, min_points=0,
                                                     source=frame.source, remove_planes=o.remove_planes,
                                                     plane_tolerance=o.plane_tolerance, return_indices=True)
                view, k = cloud_view(pts[kept])
                return view, k, cloud, None
            except DepthError as e:
                view, k = cloud_view(np.zeros((0, 3)))
                return view, k, _empty_cloud(o.max_points), str(e)
        depth, _ = read_depth(frame.source, o.depth_scale)
        return self.depth_cloud(depth, frame.source)


def _load_stack(path: str, depth_scale) -> np.ndarray:
    try:
        stack = np.load(path, mmap_mode="r", allow_pickle=False)
    except (ValueError, OSError) as e:
        raise DepthError(f"{path}: cannot read the .npy stack ({e})") from None
    if stack.dtype.kind not in "fiu":
        raise DepthError(f"{path}: a depth stack must hold numbers (metres), got dtype {stack.dtype}")
    return stack


# --------------------------------------------------------------------------- documents


def frame_document(skel, skel_file, frame_result, mode: str, config, seed: int, inputs: dict, index: int,
                   cloud, note: str | None) -> dict:
    """``result.json``'s document for one frame (with ``points``, the frame's points, as
    ``fit`` writes them), plus ``frame`` and ``tracking``."""
    from ..io.fit_result import result_document

    r = frame_result
    lost = mode == "lost"
    if lost:  # no fit: the document's numbers would be NaN
        import jax.numpy as jnp

        r = r._replace(cost=jnp.float32(0), history=r.history[:0], genome=r.genome[:0])
    doc = result_document(skel, skel_file, r, config.fit, seed, inputs, cloud)
    points = len(doc["points"])
    doc["coordinates"] = doc.pop("frame")
    doc["frame"] = index
    doc["tracking"] = mode
    doc["tracking_config"] = {k: v for k, v in config.to_dict().items() if k != "fit"}
    if lost:
        for key in ("links", "params", "genome", "cost_history"):
            doc.pop(key, None)
        doc["cost"] = None
        doc["lost_because"] = note or f"{points} points, fewer than min_points {config.min_points}"
    elif mode == "tracked":
        doc["cost_history"] = doc["cost_history"][: config.generations]
    return doc


def summary(entries: list[dict], interrupted: bool = False) -> dict:
    """track.json's ``summary`` from the frames' entries."""
    tracked = [e["wall_seconds"] for e in entries if e["mode"] == "tracked"]
    globals_ = [e["wall_seconds"] for e in entries if e["mode"] == "global"]
    out = {
        "frames": len(entries),
        "fps": (len(tracked) / sum(tracked)) if tracked and sum(tracked) > 0 else None,
        "median_frame_seconds": float(np.median(tracked)) if tracked else None,
        "p90_frame_seconds": float(np.percentile(tracked, 90)) if tracked else None,
        "reinitialisations": max(0, len(globals_) - 1),
        "lost_frames": sum(e["mode"] == "lost" for e in entries),
        "tracked_frames": len(tracked),
        "global_frames": len(globals_),
        "first_frame_seconds": entries[0]["wall_seconds"] if entries else None,
        "global_median_seconds": float(np.median(globals_[1:])) if len(globals_) > 1 else None,
    }
    if interrupted:
        out["interrupted"] = True
    return out


# --------------------------------------------------------------------------- video


COLOURS = {"global": (70, 130, 255), "tracked": (40, 200, 60), "lost": (230, 40, 40)}


def overlay_frame(depth: np.ndarray, k, links, mode: str, near: float, far: float) -> np.ndarray:
    """An RGB image: the depth in grey, the fitted links drawn in the mode's colour, a border in it too."""
    from ..camera import project

    d = np.nan_to_num(np.asarray(depth, np.float32), nan=0.0)
    valid = d > 0
    g = np.zeros(d.shape, np.float32)
    if valid.any():
        lo, hi = max(near, float(d[valid].min())), min(far, float(d[valid].max()))
        g[valid] = 1.0 - np.clip((d[valid] - lo) / max(hi - lo, 1e-6), 0, 1) * 0.8
    img = np.repeat((g * 255).astype(np.uint8)[..., None], 3, -1)
    colour = np.array(COLOURS[mode], np.uint8)
    H, W = d.shape
    if links is not None:
        uv_s = project(np.asarray(links[0], np.float64), k)
        uv_e = project(np.asarray(links[1], np.float64), k)
        for a, b in zip(uv_s, uv_e):
            if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
                continue
            n = int(max(abs(b[0] - a[0]), abs(b[1] - a[1]), 1)) + 1
            t = np.linspace(0, 1, min(n, 4096))[:, None]
            p = np.round(a + t * (b - a)).astype(np.int64)
            for du in (-1, 0, 1):
                for dv in (-1, 0, 1):
                    u, v = p[:, 0] + du, p[:, 1] + dv
                    ok = (u >= 0) & (u < W) & (v >= 0) & (v < H)
                    img[v[ok], u[ok]] = colour
    b = max(2, min(H, W) // 80)
    img[:b], img[-b:], img[:, :b], img[:, -b:] = colour, colour, colour, colour
    return img


def write_video(path: str, images: list[np.ndarray], fps: float = 30.0) -> None:
    """Write the overlays atomically (a temporary file beside ``path``, renamed over it)."""
    import tempfile

    import imageio.v3 as iio

    ext = os.path.splitext(path)[1].lower()
    fd, tmp = tempfile.mkstemp(prefix=".tmp-" + os.path.basename(path) + "-", suffix=ext,
                               dir=os.path.dirname(os.path.abspath(path)))
    os.close(fd)
    try:
        if ext == ".gif":
            iio.imwrite(tmp, np.stack(images), extension=".gif", duration=int(round(1000 / fps)), loop=0)
        else:
            iio.imwrite(tmp, np.stack(images), extension=ext, fps=fps)
        os.chmod(tmp, 0o644)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def check_video(path: str) -> None:
    ext = os.path.splitext(path)[1].lower()
    if ext not in VIDEO_EXTENSIONS:
        raise ConfigError(f"--video {path}: expected a .gif or .mp4 file")
    if ext == ".mp4":
        try:
            import imageio_ffmpeg  # noqa: F401
        except ImportError:
            raise ConfigError(f"--video {path}: writing .mp4 needs the imageio-ffmpeg package "
                              "(pip install imageio-ffmpeg); or give a .gif") from None
    check_output_path(path, "--video")


# --------------------------------------------------------------------------- progress


def _fps_text(times: list[float]) -> str:
    recent = times[-30:]
    return f"{len(recent) / sum(recent):.1f} fps" if recent and sum(recent) > 0 else "-- fps"


# --------------------------------------------------------------------------- the command


def run(args: argparse.Namespace) -> int:
    from ..io.atomic import write_json
    from ..io.fit_result import file_sha256
    from ..pipeline import load_fit_skeleton
    from ..tracking import Tracker
    from .fit import input_options
    from .track_sequences import check_combinations, run_sequences

    check_combinations(args)
    if args.sequences is not None:
        return run_sequences(args)
    config = track_config_from_args(args)
    check_search_options(args)
    if not os.path.isdir(args.out_dir):
        raise ConfigError(f"--out-dir {args.out_dir}: not a directory")
    frames = expand_inputs(args.depth)
    if any(f.name.casefold() == "track" for f in frames):
        raise ConfigError("an input named track.* would write track.json, the summary, in --out-dir; rename it")
    stack = _load_stack(frames[0].source, args.depth_scale) if frames[0].index is not None else None
    args.depth = [frames[0].source] if stack is not None else [f.source for f in frames]
    options = input_options(args)
    outputs = [os.path.join(args.out_dir, f.name + ".json") for f in frames]
    summary_path = os.path.join(args.out_dir, "track.json")
    inputs = {os.path.abspath(f.source) for f in frames} | {os.path.abspath(p) for p in (args.background,) if p}
    for out in outputs + [summary_path] + ([args.video] if args.video else []):
        if os.path.abspath(out) in inputs:
            raise ConfigError(f"{out} is also an input; refusing to overwrite an input")
    check_output_path(summary_path, "--out-dir")
    if args.video:
        check_video(args.video)
    skel, skel_file = load_fit_skeleton(args.skeleton, args.search_lengths, args.max_capsules, args.search_scale)
    robot = robot_record(args, skel_file)
    reader = FrameReader(options, stack)
    per_frame = [reader.read(f) for f in frames]  # every frame read and checked before the first search
    tracker = Tracker(skel, config, seed=args.seed)
    config = tracker.config
    bar = FrameBar(len(frames), args.quiet)
    entries, tracked_times, images = [], [], []
    stack_sha = file_sha256(frames[0].source) if stack is not None else None
    interrupted = True
    try:
        for i, (f, out, (depth, k, cloud, note)) in enumerate(zip(frames, outputs, per_frame)):
            label = f"frame {i + 1}/{len(frames)}"

            def progress(gen, best, evals, label=label):
                bar.show(f"{label}  global search: generation {gen}/{config.fit.generations * config.fit.searches}", i)

            bar.show(f"{label}  {_fps_text(tracked_times)}", i)
            result = tracker.update(cloud, progress)
            mode, wall = tracker.mode, float(result.wall_time)
            if mode == "tracked":
                tracked_times.append(wall)
            record = _input_record(f, options, k, cloud, stack_sha)
            doc = frame_document(skel, skel_file, result, mode, config, args.seed, record, i, cloud, note)
            doc["skeleton"].update(robot)
            write_json(out, doc)
            entries.append({"input": f.source if f.index is None else f.name,  # the path as given
                            "frame": i, "mode": mode, "cost": doc["cost"], "wall_seconds": wall})
            if args.video:
                links = None if mode == "lost" else (np.asarray(result.links.start), np.asarray(result.links.end))
                images.append(overlay_frame(depth, k, links, mode, options.near, options.far))
            n_re = sum(e["mode"] == "global" for e in entries) - 1
            bar.show(f"{label}  {mode:7s}  {_fps_text(tracked_times)}  (re-inits {max(n_re, 0)}, lost "
                     f"{sum(e['mode'] == 'lost' for e in entries)})", i + 1)
        interrupted = False
    finally:
        bar.close()
        if entries:  # also after Ctrl-C: the frames written so far and their summary
            write_json(summary_path, {"skeleton": skel.name, "frames": entries,
                                      "summary": summary(entries, interrupted)})
    if args.video:
        write_video(args.video, images)
    if not args.quiet:
        s = summary(entries)
        fps = f"{s['fps']:.1f} frames/s tracked (median {1000 * s['median_frame_seconds']:.0f} ms)" \
            if s["fps"] else "no tracked frame"
        print(f"{skel.name}: {s['frames']} frames, {fps}, {s['reinitialisations']} re-initialisations, "
              f"{s['lost_frames']} lost -> {args.out_dir}" + (f", {args.video}" if args.video else ""), flush=True)
    return 0


def _input_record(frame: Frame, options, k, cloud, stack_sha) -> dict:
    """What a frame's document records about its input (as ``fit`` does, and the frame in a stack)."""
    from ..io.fit_result import file_sha256

    base = {"near": options.near, "far": options.far, "max_points": options.max_points,
            "points_used": int(np.sum(np.asarray(cloud.weights) > 0)), "sample_seed": options.sample_seed,
            "remove_planes": options.remove_planes, "plane_tolerance": options.plane_tolerance}
    if frame.cloud_file:
        return {"cloud": os.path.basename(frame.source), "cloud_sha256": file_sha256(frame.source),
                "cloud_scale": options.cloud_scale, **base}
    rec = {"depth": os.path.basename(frame.source),
           "depth_sha256": stack_sha if frame.index is not None else file_sha256(frame.source),
           "background": os.path.basename(options.background) if options.background else None,
           "background_sha256": file_sha256(options.background),
           "intrinsics": {"fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy, "width": k.width, "height": k.height},
           "depth_scale": None if frame.index is not None or frame.source.lower().endswith(".npy")
           else options.depth_scale, **base}  # float pixels are metres, not scaled
    if frame.index is not None:
        rec["stack_frame"] = frame.index
    return rec


__all__ = ["register", "run", "expand_inputs", "summary", "overlay_frame"]
