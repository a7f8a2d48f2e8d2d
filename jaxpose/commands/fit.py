"""``jaxpose fit``: fit a skeleton to a depth image or a point cloud."""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import math
import os
import re
import sys
import warnings

from ..errors import ConfigError
from ..objective import ObjectiveConfig
from ..search import FitConfig
from .progress import ProgressBar, check_output_path
from .robot_options import add_search_options, check_search_options

BATCH = 8  # images per device in one batch of several inputs (--batch)


def register(sub) -> None:
    p = sub.add_parser("fit", help="fit a skeleton to depth images or point clouds",
                       description="Fit a skeleton to a depth image or a point cloud (several with --out-dir: "
                                   "every input is checked first, the search is compiled once).")
    p.add_argument("depth", metavar="INPUT", nargs="+",  # written together, before or after the options
                   help="depth image: 16-bit PNG (millimetres) or 2-D .npy (metres); or point cloud in the "
                        "sensor's frame: .ply, .pcd, .xyz, float (N, 3) or (H, W, 3) .npy (metres, see "
                        "--cloud-scale, --viewpoint)")
    p.add_argument("--skeleton", required=True, help="skeleton file (.toml/.json/.urdf/.xml) or a shipped name")
    p.add_argument("--intrinsics", help="depth images: 'kinect', 'fx,fy,cx,cy' or a JSON file (default kinect)")
    p.add_argument("--depth-scale", type=float, help="depth images: metres per PNG unit (default 0.001)")
    p.add_argument("--cloud-scale", type=float,
                   help="point clouds: metres per unit of the file's coordinates (default 1; 0.001 for millimetres)")
    p.add_argument("--viewpoint", metavar="TX,TY,TZ,QW,QX,QY,QZ",
                   help="point clouds: the sensor's pose in the cloud's frame, translation in the file's unit "
                        "(default: a PCD file's VIEWPOINT, else the origin looking along +z)")
    p.add_argument("--near", type=float, default=0.3, help="nearest depth kept, metres (default 0.3)")
    p.add_argument("--far", type=float, default=8.0, help="farthest depth kept, metres (default 8)")
    p.add_argument("--scale", type=float, default=None, metavar="S",
                   help="the subject's global scale when known (default: searched; 1 for a robot file, "
                        "its robot's size)")
    add_search_options(p)
    p.add_argument("--background", help="depth images: background depth image to subtract (same size)")
    p.add_argument("--remove-planes", type=int, default=0, metavar="N",
                   help="drop the points of up to N largest planes (a floor, a wall) before fitting; for an "
                        "image or cloud without a background image (default 0)")
    p.add_argument("--max-points", type=int, default=1024, help="points sampled from the image or cloud (default 1024)")
    p.add_argument("--algorithm", default="ga", help="ga (default), hc, cma_es or another evosax strategy")
    p.add_argument("--population", type=int, default=FitConfig.population)
    p.add_argument("--generations", type=int, default=FitConfig.generations,
                   help="generations (default: 4 per searched gene, within 100..300 in whole epochs: "
                        "spider 150, humanoid 300)")
    p.add_argument("--islands", type=int, default=FitConfig.islands,
                   help=f"independent populations searched side by side (default {FitConfig.islands})")
    p.add_argument("--coarse-points", type=int, default=FitConfig.coarse_points,
                   help="coarse-to-fine (GA only): score on this many points during the first half of the "
                        "generations, then on all (default 0: off)")
    p.add_argument("--tie-lengths", action="store_true",
                   help="one length for alike links (left and right, a spider's legs; "
                        "default: each searched on its own)")
    p.add_argument("--no-refine", action="store_true", help="no gradient refinement (memetic or final)")
    p.add_argument("--one-search", action="store_true",
                   help="the staged search alone, not the portfolio of it and a search without staging "
                        "(before the turn searches, if any; folded and crossed limbs are placed less often)")
    p.add_argument("--turns", type=int, default=FitConfig.turns, metavar="N",
                   help="after the searches, turn the answer's body half a turn about N of its principal axes "
                        "(0-3) and search again from each, the root's orientation held near it: for a body found "
                        f"the wrong way round (one search's time each; default {FitConfig.turns})")
    p.add_argument("--restarts", type=int, default=FitConfig.restarts, metavar="K",
                   help="run the whole fit (its searches and turns) K times with keys of their own and keep the "
                        "cheapest answer: more limbs of hard poses placed, at K times the time "
                        f"(default {FitConfig.restarts})")
    p.add_argument("--restart-apart", type=float, default=FitConfig.restart_apart, metavar="F",
                   help="with --restarts: run a restart only when the answers so far disagree, their links further "
                        "apart than F times the cloud's spread (0: every restart runs; "
                        f"default {FitConfig.restart_apart:g})")
    p.add_argument("--limb-sweep", type=int, default=FitConfig.limb_sweep, metavar="N",
                   help="after each search, search every limb again with the rest of the body held, N "
                        f"generations each (0: off; default {FitConfig.limb_sweep})")
    p.add_argument("--pivot-sweep", type=int, default=FitConfig.pivot_sweep, metavar="N",
                   help="after each search and before the limb sweep, hold every limb where it is and search the "
                        "rest of the body again around it, N generations each "
                        f"(0: off; default {FitConfig.pivot_sweep})")
    p.add_argument("--time-budget", type=float, metavar="SECONDS",
                   help="anytime fit: end the search after the epoch in which this many seconds of search "
                        "(compilation excluded) have passed, then refine and write the best as usual")
    p.add_argument("--hypotheses", type=int, default=1, metavar="K",
                   help="also record the K best distinct poses the search found, with their costs, under "
                        "'hypotheses' in the result (an occluded limb can be in two places; default 1: the answer)")
    p.add_argument("--sigma-factor", type=float, default=ObjectiveConfig.sigma_factor,
                   help="sigma = this x the cloud's spread (1: the paper's objective; "
                        f"default {ObjectiveConfig.sigma_factor})")
    p.add_argument("--free-space-weight", type=float, default=ObjectiveConfig.free_space_weight,
                   help="weight of the free-space term (0: the paper's objective alone)")
    p.add_argument("--collision-weight", type=float, default=ObjectiveConfig.collision_weight,
                   help="weight of the term that keeps links from passing through each other "
                        f"(0: off; default {ObjectiveConfig.collision_weight})")
    p.add_argument("--max-range", type=float, metavar="METRES",
                   help="the depth sensor measures nothing beyond this depth (a Kinect v1: 4): a link beyond it "
                        "where nothing was measured is not taken for empty space (default: no limit)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", help="result JSON (default result.json; one input only)")
    p.add_argument("--plot", help="PNG with the fitted skeleton drawn over the depth image, or over a "
                                     "view of the cloud from the sensor (needs matplotlib; one input only)")
    p.add_argument("--out-dir", metavar="DIR",
                   help="write DIR/<input name>.json for every input (needed for several inputs)")
    p.add_argument("--plots", action="store_true", help="with --out-dir: also DIR/<input name>.png")
    p.add_argument("--devices", type=int, metavar="N",
                   help="several inputs: fit them in batches sharded over the first N devices of this machine "
                        "(default: every device; on a machine whose only device is its CPU the inputs are "
                        "fitted one by one unless --devices or --batch is given); one input: one fit with its "
                        "islands split over the first N devices (--islands a multiple of N; without --devices "
                        "the fit runs on one device, epoch by epoch)")
    p.add_argument("--batch", type=int, metavar="K",
                   help=f"several inputs: images per device in one compiled batch (default {BATCH}; results "
                        "are written after each batch)")
    p.add_argument("--resume", action="store_true",
                   help="with --out-dir: skip the inputs whose result (and plot, with --plots) is already written")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


# The settings' names in the config classes' errors, as the command line's flags.
FLAGS = {
    "population": "--population", "generations": "--generations", "islands": "--islands",
    "coarse_points": "--coarse-points", "limb_sweep": "--limb-sweep", "turns": "--turns",
    "restarts": "--restarts", "restart_apart": "--restart-apart", "scale": "--scale",
    "pivot_sweep": "--pivot-sweep", "objective.sigma_factor": "--sigma-factor",
    "objective.free_space_weight": "--free-space-weight", "objective.collision_weight": "--collision-weight",
    "objective.max_range": "--max-range",
    "near": "--near", "far": "--far", "depth_scale": "--depth-scale", "cloud_scale": "--cloud-scale",
    "viewpoint": "--viewpoint", "max_points": "--max-points", "remove_planes": "--remove-planes",
}


@contextlib.contextmanager
def as_flags():
    """A :class:`ConfigError` of :meth:`FitConfig.validate` or :meth:`InputOptions.validate`
    re-raised with the settings it names (at the start, or after ``/ ``) as flags."""
    try:
        yield
    except ConfigError as e:
        name = re.compile(r"(?:^|(?<=/ ))[a-z_.]+")
        raise ConfigError(name.sub(lambda m: FLAGS.get(m.group(0), m.group(0)), str(e))) from None


def _input_values(args):
    """The input settings of the command line, not yet checked against the inputs' kinds."""
    from ..pipeline import InputOptions

    return InputOptions(
        args.intrinsics or "kinect", 0.001 if args.depth_scale is None else args.depth_scale, args.near, args.far,
        args.background, max_points=args.max_points, cloud_scale=1.0 if args.cloud_scale is None else args.cloud_scale,
        viewpoint=args.viewpoint, remove_planes=args.remove_planes,
    )


def config_from_args(args) -> FitConfig:
    """The fit settings of the command line, validated with the input settings by their
    classes; :class:`ConfigError` names the offending option."""
    if args.seed < 0 or args.seed >= 2**32:
        raise ConfigError(f"--seed must lie in 0 .. 2**32-1, got {args.seed}")
    if args.hypotheses < 1:
        raise ConfigError(f"--hypotheses must be >= 1, got {args.hypotheses}")
    if args.time_budget is not None and not (math.isfinite(args.time_budget) and args.time_budget > 0):
        raise ConfigError(f"--time-budget must be a positive number of seconds, got {args.time_budget}")
    cfg = FitConfig(
        algorithm=args.algorithm,
        population=args.population,
        generations=args.generations,
        islands=args.islands,
        coarse_points=args.coarse_points,
        tie_lengths=args.tie_lengths,
        limb_sweep=args.limb_sweep,
        pivot_sweep=args.pivot_sweep,
        turns=args.turns,
        restarts=args.restarts,
        restart_apart=args.restart_apart,
        scale=args.scale,
        objective=ObjectiveConfig(free_space_weight=args.free_space_weight, sigma_factor=args.sigma_factor,
                                  collision_weight=args.collision_weight, max_range=args.max_range),
    )
    if args.no_refine:
        cfg = dataclasses.replace(cfg, memetic_steps=0, final_refine_steps=0)
    if args.one_search:
        cfg = dataclasses.replace(cfg, staged_alternatives=())
    with as_flags():
        _input_values(args).validate()
        return cfg.validate()


def _same_file(a: str | None, b: str | None) -> bool:
    if not a or not b:
        return False
    try:
        return os.path.samefile(a, b)
    except OSError:
        return os.path.abspath(a) == os.path.abspath(b)


def outputs(args) -> list[tuple[str, str, str | None]]:
    """``(input, result JSON, plot PNG or None)`` for every input; :class:`ConfigError`
    for a combination of --out/--plot/--out-dir/--plots that does not fit the inputs."""
    if args.out_dir is None:
        if len(args.depth) > 1:
            raise ConfigError(f"{len(args.depth)} inputs: give --out-dir DIR (each result goes to DIR/<name>.json)")
        if args.plots:
            raise ConfigError("--plots works with --out-dir; for one input give --plot FILE")
        return [(args.depth[0], args.out or "result.json", args.plot)]
    for flag in ("out", "plot"):
        if getattr(args, flag):
            raise ConfigError(f"--{flag} and --out-dir exclude each other (with --out-dir every result is "
                              "DIR/<name>.json, plots DIR/<name>.png with --plots)")
    if not os.path.isdir(args.out_dir):
        raise ConfigError(f"--out-dir {args.out_dir}: not a directory")
    seen, out = {}, []
    for path in args.depth:
        stem = os.path.splitext(os.path.basename(path))[0]
        if stem.casefold() in seen:  # case-insensitive file systems would merge A.json and a.json
            raise ConfigError(f"inputs {seen[stem.casefold()]} and {path} would both write {stem}.json in --out-dir")
        seen[stem.casefold()] = path
        out.append((path, os.path.join(args.out_dir, stem + ".json"),
                    os.path.join(args.out_dir, stem + ".png") if args.plots else None))
    return out


def check_conflicts(args, jobs) -> None:
    """Outputs must differ from each other and from every input."""
    from ..io.cloud_file import is_cloud_file
    from ..io.skeleton_file import resolve_skeleton_path

    inputs = [("the point cloud" if is_cloud_file(p) else "the depth image", p) for p in args.depth]
    inputs += [("--background", args.background), ("--skeleton", resolve_skeleton_path(args.skeleton)),
               ("--intrinsics", args.intrinsics)]
    flags = ("--out-dir", "--plots") if args.out_dir else ("--out", "--plot")
    for _, result, plot in jobs:
        if _same_file(result, plot):
            raise ConfigError(f"--out and --plot name the same file {result}")
        for flag, out in zip(flags, (result, plot)):
            for what, path in inputs:
                if _same_file(out, path):
                    raise ConfigError(f"{flag} {out} is also {what}; refusing to overwrite an input")


def input_options(args):
    """The input settings; :class:`ConfigError` for an option that applies to none of the inputs
    (an option for depth images when every input is a point cloud, or the other way round)."""
    from ..io.cloud_file import is_cloud_file

    clouds = [is_cloud_file(p) for p in args.depth]
    subject = args.depth[0] if len(clouds) == 1 else "every input"
    if all(clouds):
        for flag, value in (("--intrinsics", args.intrinsics), ("--depth-scale", args.depth_scale),
                            ("--background", args.background)):
            if value is not None:
                raise ConfigError(f"{flag} is for depth images; {subject} is a point cloud "
                                  "(see --cloud-scale and --viewpoint)")
    if not any(clouds):
        for flag, value in (("--cloud-scale", args.cloud_scale), ("--viewpoint", args.viewpoint)):
            if value is not None:
                raise ConfigError(f"{flag} is for point clouds; {subject} is a depth image")
    return _input_values(args)


def _show_input_warning(message, category, filename, lineno, file=None, line=None):
    """Print an :class:`~jaxpose.errors.InputWarning` as one ``jaxpose: warning:`` line (before the
    search starts, so it stands above the progress bar); other warnings as Python prints them."""
    from ..errors import InputWarning

    if issubclass(category, InputWarning):
        print(f"jaxpose: warning: {message}", file=sys.stderr, flush=True)
    else:
        sys.stderr.write(warnings.formatwarning(message, category, filename, lineno, line))


def finished(job) -> bool:
    """Whether an input's outputs are all written (``--resume``): results are written
    atomically, so a file that exists is whole."""
    _, result, plot = job
    return os.path.isfile(result) and (plot is None or os.path.isfile(plot))


def batched(args, jobs) -> bool:
    """Whether the inputs are fitted as sharded batches (:func:`jaxpose.parallel.fit_batch`):
    several inputs, or several processes; not with --hypotheses or --time-budget, which
    fit one input at a time.  :class:`ConfigError` for batch options that cannot apply."""
    import jax

    from .. import distributed

    distributed.check()
    if args.batch is not None and args.batch < 1:
        raise ConfigError(f"--batch must be >= 1 image per device, got {args.batch}")
    if args.devices is not None and args.devices < 1:
        raise ConfigError(f"--devices must be >= 1, got {args.devices}")
    many = len(jobs) > 1 or jax.process_count() > 1
    if args.devices is not None and args.devices > jax.local_device_count():
        raise ConfigError(f"--devices must lie within 1 .. {jax.local_device_count()} (this machine's "
                          f"{jax.devices()[0].platform.upper()} devices), got {args.devices}")
    if not many and args.devices is not None and args.islands % args.devices:
        raise ConfigError(f"--devices {args.devices}: one input's {args.islands} islands do not split evenly over "
                          f"{args.devices} devices (--islands must be a multiple of --devices)")
    if args.resume and args.out_dir is None:
        raise ConfigError("--resume works with --out-dir (it skips the results already in DIR)")
    one_by_one = [f for f, on in (("--hypotheses", args.hypotheses > 1), ("--time-budget", args.time_budget))
                  if on]
    if one_by_one and jax.process_count() > 1:
        raise ConfigError(f"{one_by_one[0]} fits one input at a time, on one process; this run has "
                          f"{jax.process_count()} processes")
    if one_by_one and args.devices is not None:
        raise ConfigError(f"{one_by_one[0]} fits one input at a time, on one device: not with --devices")
    # one CPU device fits a batch no faster than one image after another (measured in
    # docs/scaling.md), and one by one each result equals a run on that input alone
    lone_cpu = jax.device_count() == 1 and jax.devices()[0].platform == "cpu"
    explicit = args.devices is not None or args.batch is not None
    return many and not one_by_one and (explicit or not lone_cpu)


def run(args: argparse.Namespace) -> int:
    from ..io.cloud_file import is_cloud_file
    from ..io.atomic import write_json
    from ..pipeline import check_input, fit_file, load_fit_skeleton

    config = config_from_args(args)
    jobs = outputs(args)
    check_conflicts(args, jobs)
    check_search_options(args)
    flags = ("--out-dir", "--plots") if args.out_dir else ("--out", "--plot")
    for _, result, plot in jobs:
        check_output_path(result, flags[0])
        if plot:
            check_output_path(plot, flags[1])
    if any(plot for _, _, plot in jobs):
        from ..viz import _pyplot

        _pyplot()  # fail before the search if matplotlib is missing
    options = input_options(args)
    from ..io.capsules import MAX_CAPSULES

    skel, skel_file = load_fit_skeleton(args.skeleton, args.search_lengths, args.max_capsules, args.search_scale)
    capsules = MAX_CAPSULES if args.max_capsules is None else args.max_capsules  # the record (robot files)
    config = config.for_skeleton(skel)  # the generations: the bar's total
    # a mixed batch: the depth-image options (a background) leave the clouds alone
    per_input = {path: dataclasses.replace(options, background=None) if is_cloud_file(path) else options
                 for path, _, _ in jobs}
    if batched(args, jobs):
        from .fit_batch import run_batches

        return run_batches(args, jobs, skel, skel_file, config, per_input)
    if args.resume:
        jobs = [job for job in jobs if not finished(job)]
    if len(jobs) > 1:
        for path, _, _ in jobs:  # every input is read and checked before the first search
            check_input(path, per_input[path])
    for i, (path, result, plot) in enumerate(jobs):
        label = f"{i + 1}/{len(jobs)} {os.path.basename(path)} " if len(jobs) > 1 else ""
        bar = ProgressBar(config.generations * config.searches, quiet=args.quiet, label=label)
        try:
            with warnings.catch_warnings():
                warnings.showwarning = _show_input_warning
                out = fit_file(path, skel, config, args.seed, per_input[path], progress=bar.update,
                                     search_lengths=args.search_lengths, search_scale=args.search_scale,
                                     skeleton_file=skel_file,
                                     max_capsules=capsules, hypotheses=args.hypotheses,
                                     time_budget=args.time_budget, devices=args.devices)
        finally:
            bar.close()  # end the progress line, also before an error message or Ctrl-C
        msg = (f"{label}{out.skeleton.name}: cost {out.document['cost']:.5f}, "
               f"{out.document['evaluations']['objective']} evaluations, "
               f"{out.document['timing']['wall_seconds']:.1f} s -> {result}")
        if plot:  # the plot first: a result file always has its plot beside it
            from ..viz import overlay_figure, save_figure

            fig = overlay_figure(out.depth, out.intrinsics, out.document["links"],
                                 title=f"{out.skeleton.name} ({config.algorithm}), cost {out.document['cost']:.4f}")
            save_figure(fig, plot)
            msg += f", {plot}"
        write_json(result, out.document)
        if not args.quiet:
            print(msg, flush=True)
    return 0


__all__ = ["register", "run", "config_from_args", "input_options", "outputs"]
