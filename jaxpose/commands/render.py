"""``jaxpose render``: a synthetic depth image (16-bit PNG, millimetres) and its ground truth."""

from __future__ import annotations

import argparse
import os
import sys

from .robot_options import add_max_capsules, check_max_capsules


def register(sub) -> None:
    p = sub.add_parser(
        "render",
        help="render a synthetic Kinect-like depth image of a posed skeleton, with its ground truth",
        description="Render a skeleton in a random, rest or given pose seen from a camera on an orbit around it. "
        "Writes a 16-bit PNG in millimetres and optionally a ground-truth JSON, the background-only image and "
        "the image as a point cloud (--cloud).",
    )
    p.add_argument("--skeleton", required=True, metavar="FILE",
                   help="skeleton file or shipped name (spider, humanoid, ...)")
    add_max_capsules(p)
    p.add_argument("--pose", default="random", metavar="POSE",
                   help="'random' (seeded natural pose), 'rest', or a truth/result JSON (default: random)")
    p.add_argument("--seed", type=int, default=0, help="seed of the pose, clutter and sensor noise (default 0)")
    p.add_argument("--elevation", type=float, default=20.0, metavar="DEG",
                   help="camera inclination below the horizontal, degrees (default 20)")
    p.add_argument("--azimuth", type=float, default=0.0, metavar="DEG",
                   help="camera direction about the vertical, degrees (0: on the skeleton's +x side)")
    p.add_argument("--distance", type=float, default=None, metavar="M",
                   help="camera distance to the subject's centre, metres (default: frame the subject)")
    p.add_argument("--intrinsics", default="kinect", help="'kinect', 'fx,fy,cx,cy' or a JSON file (default kinect)")
    p.add_argument("--size", default=None, metavar="WxH", help="image size, e.g. 320x240 (intrinsics scale with it)")
    p.add_argument("--noise", action=argparse.BooleanOptionalAction, default=True,
                   help="apply the Kinect v1 sensor model (noise, quantisation, missing pixels; default on)")
    p.add_argument("--floor", action="store_true", help="render a floor under the subject")
    p.add_argument("--clutter", type=int, nargs="?", const=3, default=0, metavar="N",
                   help="render N objects around the subject (default 0; 3 without a number)")
    p.add_argument("--out", required=True, metavar="PNG", help="depth image to write (16-bit PNG, millimetres)")
    p.add_argument("--truth", default=None, metavar="JSON", help="ground truth to write")
    p.add_argument("--background-out", default=None, metavar="PNG",
                   help="background-only depth image to write (needs --floor or --clutter)")
    p.add_argument("--cloud", default=None, metavar="PLY",
                   help="also write every measured pixel of the depth image as a point cloud (binary PLY, "
                        "camera frame, metres)")
    p.add_argument("--sequence", type=int, default=None, metavar="FRAMES",
                   help="render a motion sequence of FRAMES frames at 30 fps instead: --out is then a folder "
                        "(depth/, truth/, background.png, index.json; docs/tracking.md)")
    p.add_argument("--gap", default=None, metavar="FIRST,LENGTH",
                   help="with --sequence: the subject is out of view for LENGTH frames from FIRST, then back elsewhere")
    p.set_defaults(func=run)


def run_sequence(args) -> int:
    """``--sequence``: a motion sequence with its truth per frame (jaxpose.sequences)."""
    from .. import sequences as S
    from ..errors import ConfigError
    from ..io.depth_file import parse_intrinsics
    from ..io.sequence_file import write_sequence
    from ..io.skeleton_file import load_skeleton
    from ..render import SensorModel

    if not 1 <= args.sequence <= 10000:
        raise ConfigError(f"--sequence {args.sequence}: expected 1..10000 frames")
    gap = None
    if args.gap:
        try:
            gap = tuple(int(v) for v in args.gap.split(","))
            assert len(gap) == 2 and gap[0] >= 1 and gap[1] >= 1 and sum(gap) < args.sequence
        except (ValueError, AssertionError):
            raise ConfigError(f"--gap {args.gap!r}: expected FIRST,LENGTH with 1 <= FIRST and FIRST + LENGTH "
                              f"< {args.sequence} frames") from None
    if not 0 <= args.seed < 2**32:
        raise ConfigError(f"--seed must lie in 0 .. 2**32-1, got {args.seed}")
    if os.path.exists(args.out) and not os.path.isdir(args.out):
        raise ConfigError(f"--out {args.out}: with --sequence, a folder (this is a file)")
    skel = load_skeleton(args.skeleton, max_capsules=args.max_capsules)
    k = parse_intrinsics(args.intrinsics)
    if args.size:
        w, h = _size(args.size)
        sx, sy = w / k.width, h / k.height
        k = k._replace(fx=k.fx * sx, fy=k.fy * sy, cx=(k.cx + 0.5) * sx - 0.5, cy=(k.cy + 0.5) * sy - 0.5,
                       width=w, height=h)
    sensor = SensorModel() if args.noise else None
    kind = {"spider": S.spider_sequence, "humanoid": S.humanoid_sequence}.get(skel.name)
    if kind is not None:
        seq = kind(skel, seed=args.seed, frames=args.sequence, gap=gap, k=k, sensor=sensor)
    else:
        seq = S.robot_sequence(skel, skel.name, seed=args.seed, frames=args.sequence, gap=gap, k=k, sensor=sensor)
    os.makedirs(args.out, exist_ok=True)
    write_sequence(args.out, skel, seq, args.skeleton, sensor)
    print(f"{args.out}: {args.sequence} frames of {skel.name} ({seq.name}, seed {args.seed})"
          + (f", out of view in frames {gap[0]}..{gap[0] + gap[1] - 1}" if gap else ""))
    return 0


def _size(spec: str):
    from ..errors import ConfigError

    try:
        w, h = (int(v) for v in spec.lower().split("x"))
    except ValueError:
        raise ConfigError(f"--size {spec!r}: expected WIDTHxHEIGHT, e.g. 320x240") from None
    if not (8 <= w <= 4096 and 8 <= h <= 4096):
        raise ConfigError(f"--size {spec!r}: width and height must lie in 8..4096")
    return w, h


def run(args) -> int:
    if args.sequence is not None:
        return run_sequence(args)
    import numpy as np

    from ..datasets import default_distance, random_pose, render_orbit, subject_frame
    from ..errors import ConfigError
    from ..io.depth_file import parse_intrinsics
    from ..io.skeleton_file import load_skeleton
    from ..io.truth import read_pose, write_view
    from ..render import SensorModel
    from ..skeleton import rest_pose

    from .progress import check_output_path

    if not 0 <= args.seed < 2**32:
        raise ConfigError(f"--seed must lie in 0 .. 2**32-1, got {args.seed}")
    outputs = [(flag, p) for flag, p in (("--out", args.out), ("--truth", args.truth),
                                         ("--background-out", args.background_out), ("--cloud", args.cloud)) if p]
    for i, (flag, p) in enumerate(outputs):
        for flag2, p2 in outputs[i + 1:]:
            if os.path.abspath(p) == os.path.abspath(p2):
                raise ConfigError(f"{flag} and {flag2} name the same file {p}")
    check_max_capsules(args, args.skeleton)
    skel = load_skeleton(args.skeleton, max_capsules=args.max_capsules)
    k = parse_intrinsics(args.intrinsics)
    if not args.size and not (8 <= k.width <= 4096 and 8 <= k.height <= 4096):
        raise ConfigError(f"--intrinsics {args.intrinsics}: image size {k.width}x{k.height} must lie in 8..4096 "
                          "(or pass --size)")
    if args.size:
        w, h = _size(args.size)
        sx, sy = w / k.width, h / k.height
        k = k._replace(fx=k.fx * sx, fy=k.fy * sy, cx=(k.cx + 0.5) * sx - 0.5, cy=(k.cy + 0.5) * sy - 0.5,
                       width=w, height=h)
    if args.clutter < 0 or args.clutter > 50:
        raise ConfigError(f"--clutter {args.clutter}: expected 0..50 objects")
    if args.distance is not None and not (np.isfinite(args.distance) and args.distance > 0):
        raise ConfigError(f"--distance {args.distance}: must be a positive number of metres")
    if not (np.isfinite(args.elevation) and -90 <= args.elevation <= 90):
        raise ConfigError(f"--elevation {args.elevation}: must lie in [-90, 90] degrees")
    if not np.isfinite(args.azimuth):
        raise ConfigError(f"--azimuth {args.azimuth}: must be a number of degrees")
    if args.background_out and not (args.floor or args.clutter):
        raise ConfigError("--background-out needs a background: add --floor and/or --clutter")
    for flag, p in outputs:
        check_output_path(p, flag)

    if args.gap:
        raise ConfigError("--gap works with --sequence")
    if args.pose == "random":
        pose = random_pose(skel, args.seed)
    elif args.pose == "rest":
        pose = rest_pose(skel)
    else:
        pose = read_pose(args.pose, skel, world=True)
    sensor = SensorModel() if args.noise else None
    distance = args.distance or default_distance(subject_frame(skel, pose)[1], k)
    view = render_orbit(skel, pose, args.elevation, args.azimuth, distance, k, floor=args.floor,
                        clutter=args.clutter, sensor=sensor, seed=args.seed)
    seen = int((view.depth > 0).sum())
    if sensor is not None:
        clean = int((view.clean > 0).sum())
        far = float(np.max(view.clean)) if clean else 0.0
        if far > sensor.max_range and seen < 0.5 * clean:
            print(f"jaxpose: warning: the subject reaches {far:.1f} m, beyond the sensor's {sensor.max_range:.1f} m "
                  f"range: only {seen} of {clean} pixels were measured; try a smaller --distance", file=sys.stderr)
    meta = {"pose": args.pose, "seed": args.seed, "elevation_deg": args.elevation, "azimuth_deg": args.azimuth,
            "distance": float(distance), "floor": bool(args.floor), "clutter": int(args.clutter)}
    if args.truth:
        write_view(args.out, args.truth, skel, view, args.background_out, args.skeleton, sensor, meta)
    else:
        from ..io.depth_file import save_depth_png

        save_depth_png(args.out, view.depth)
        if args.background_out:
            save_depth_png(args.background_out, view.background)
    if args.cloud:
        from ..camera import depth_to_points
        from ..io.cloud_file import save_points_ply
        from ..io.depth_file import load_depth

        stored = load_depth(args.out)  # the image as written (millimetres), so that both inputs hold the same depths
        pts, valid = depth_to_points(stored, k)
        save_points_ply(args.cloud, pts[valid])
    print(f"{args.out}: {k.width}x{k.height} depth image of {skel.name} ({seen} pixels with depth)"
          + (f"; cloud {args.cloud}" if args.cloud else "")
          + (f"; truth {args.truth}" if args.truth else "")
          + (f"; background {args.background_out}" if args.background_out else ""))
    return 0

