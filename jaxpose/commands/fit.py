"""``jaxpose fit``: fit a skeleton to a depth image."""

from __future__ import annotations

import argparse
import dataclasses

from ..errors import ConfigError
from ..objective import ObjectiveConfig
from ..search import FitConfig
from .progress import ProgressBar, check_output_path


def register(sub) -> None:
    p = sub.add_parser("fit", help="fit a skeleton to a depth image", description="Fit a skeleton to a depth image.")
    p.add_argument("depth", help="depth image: 16-bit PNG (millimetres) or .npy (metres)")
    p.add_argument("--skeleton", required=True, help="skeleton file (.toml/.json/.urdf/.xml) or a shipped name")
    p.add_argument("--intrinsics", default="kinect", help="'kinect', 'fx,fy,cx,cy' or a JSON file (default kinect)")
    p.add_argument("--depth-scale", type=float, default=0.001, help="metres per PNG unit (default 0.001)")
    p.add_argument("--near", type=float, default=0.3, help="nearest depth kept, metres (default 0.3)")
    p.add_argument("--far", type=float, default=8.0, help="farthest depth kept, metres (default 8)")
    p.add_argument("--background", help="background depth image to subtract (same size)")
    p.add_argument("--max-points", type=int, default=1024, help="points sampled from the image (default 1024)")
    p.add_argument("--algorithm", default="ga", help="ga (default), hc, cma_es or another evosax strategy")
    p.add_argument("--population", type=int, default=FitConfig.population)
    p.add_argument("--generations", type=int, default=FitConfig.generations)
    p.add_argument("--no-refine", action="store_true", help="no gradient refinement (memetic or final)")
    p.add_argument("--free-space-weight", type=float, default=ObjectiveConfig.free_space_weight,
                   help="weight of the free-space term (0: the paper's objective alone)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--out", default="result.json", help="result JSON (default result.json)")
    p.add_argument("--plot", help="PNG with the fitted skeleton drawn over the depth image (needs matplotlib)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def config_from_args(args) -> FitConfig:
    if args.max_points < 1:
        raise ConfigError(f"--max-points must be >= 1, got {args.max_points}")
    if args.free_space_weight < 0:
        raise ConfigError(f"--free-space-weight must be >= 0, got {args.free_space_weight}")
    cfg = FitConfig(
        algorithm=args.algorithm,
        population=args.population,
        generations=args.generations,
        objective=ObjectiveConfig(free_space_weight=args.free_space_weight),
    )
    if args.no_refine:
        cfg = dataclasses.replace(cfg, memetic_every=0, final_refine_steps=0)
    return cfg.validate()


def run(args: argparse.Namespace) -> int:
    from ..io.results import write_json
    from ..pipeline import DepthOptions, fit_depth_file

    config = config_from_args(args)
    check_output_path(args.out, "--out")
    if args.plot:
        check_output_path(args.plot, "--plot")
        from ..viz import _pyplot

        _pyplot()  # fail before the search if matplotlib is missing
    options = DepthOptions(args.intrinsics, args.depth_scale, args.near, args.far, args.background,
                           max_points=args.max_points)
    bar = ProgressBar(config.generations, quiet=args.quiet)
    out = fit_depth_file(args.depth, args.skeleton, config, args.seed, options, progress=bar.update)
    bar.close()
    write_json(args.out, out.document)
    msg = (f"{out.skeleton.name}: cost {out.document['cost']:.5f}, "
           f"{out.document['evaluations']['objective']} evaluations, "
           f"{out.document['timing']['wall_seconds']:.1f} s -> {args.out}")
    if args.plot:
        from ..viz import overlay_figure, save_figure

        fig = overlay_figure(out.depth, out.intrinsics, out.document["links"],
                             title=f"{out.skeleton.name} ({config.algorithm}), cost {out.document['cost']:.4f}")
        save_figure(fig, args.plot)
        msg += f", {args.plot}"
    if not args.quiet:
        print(msg)
    return 0


__all__ = ["register", "run", "config_from_args"]
