"""``jaxpose view``: a fit, or a sequence of fits, in 3D in the browser (optional extra ``view``)."""

from __future__ import annotations

import argparse
import math
import os
import sys

from ..errors import ConfigError
from .progress import check_output_path


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"invalid size {text!r} (WIDTHxHEIGHT, e.g. 960x720)") from None
    return w, h


def register(sub) -> None:
    p = sub.add_parser("view", help="look at a fit or a tracked sequence in 3D, in the browser",
                       description="Start a local web viewer (viser) of a fit, with its truth if given, or of a "
                                   "folder of fits (a tracked sequence's output: frame slider and playback), and "
                                   "print its address; or render one picture with --screenshot. Needs the "
                                   "'view' extra: pip install 'jaxpose[view]'.")
    p.add_argument("result", metavar="RESULT", help="a result .json of jaxpose fit, or a folder: a tracked "
                                                    "sequence's (track.json) or one of results (fit --out-dir)")
    p.add_argument("truth", metavar="TRUTH", nargs="?", help="a truth .json (jaxpose render --truth) drawn "
                                                             "as orange wireframe capsules; one result only")
    p.add_argument("--host", default="127.0.0.1",
                   help="address to listen on (default 127.0.0.1: this machine only; 0.0.0.0: every interface)")
    p.add_argument("--port", type=int, default=8080,
                   help="port to listen on (default 8080; when it is taken, the next free one; 0: any free one)")
    p.add_argument("--screenshot", metavar="FILE.png",
                   help="render one picture to FILE.png through a headless Chromium and exit (no window, "
                        "no display needed)")
    p.add_argument("--size", type=_size, default=(960, 720), metavar="WxH",
                   help="--screenshot: picture size in pixels (default 960x720)")
    p.add_argument("--azimuth", type=float, default=35.0,
                   help="--screenshot: degrees round the vertical from the sensor's side (default 35)")
    p.add_argument("--elevation", type=float, default=25.0,
                   help="--screenshot: degrees above the sensor's line of sight (default 25)")
    p.add_argument("--frame", type=int, default=0, help="--screenshot of a sequence: the frame (default 0: the first)")
    p.add_argument("--joints", action="store_true", help="--screenshot: draw the joint frames")
    p.set_defaults(func=run)


def _check(args) -> None:
    if not 0 <= args.port <= 65535:
        raise ConfigError(f"--port must lie in 0 .. 65535, got {args.port}")
    w, h = args.size
    if not (16 <= w <= 4096 and 16 <= h <= 4096):
        raise ConfigError(f"--size {w}x{h}: width and height must lie in 16..4096")
    for flag in ("azimuth", "elevation"):
        if not math.isfinite(getattr(args, flag)):
            raise ConfigError(f"--{flag} must be a finite number of degrees, got {getattr(args, flag)}")
    if not -89 <= args.elevation <= 89:
        raise ConfigError(f"--elevation must lie in -89 .. 89 degrees, got {args.elevation}")
    if args.screenshot:
        if os.path.splitext(args.screenshot)[1].lower() != ".png":
            raise ConfigError(f"--screenshot {args.screenshot}: the picture is a PNG; name it FILE.png")
        check_output_path(args.screenshot, "--screenshot")


def run(args: argparse.Namespace) -> int:
    from ..viewer.app import require_viser
    from ..viewer.scene import load_view

    _check(args)
    view = load_view(args.result, args.truth)
    if args.screenshot and not 0 <= args.frame < len(view.frames):
        raise ConfigError(f"--frame {args.frame}: {args.result} has frames 0 .. {len(view.frames) - 1}")
    require_viser()
    if args.screenshot:
        from ..viewer.app import find_chromium

        find_chromium()  # before the server starts
    for note in view.notes:
        print(f"jaxpose: note: {note}", file=sys.stderr, flush=True)
    if args.screenshot:
        from ..viewer.app import screenshot

        w, h = args.size
        screenshot(view, args.screenshot, w, h, args.azimuth, args.elevation, args.frame, args.joints)
        print(f"{args.result}: {args.screenshot} ({w}x{h})", flush=True)
        return 0
    from ..viewer.app import serve

    what = f"{len(view.frames)} frames" if view.is_sequence else f"{len(view.frames[0].links)} links"
    try:
        serve(view, args.host, args.port,
              on_ready=lambda url: print(f"jaxpose view: {args.result} ({what}) at {url} (Ctrl-C ends it)",
                                         flush=True))
    except KeyboardInterrupt:  # the way to end the viewer, not an interruption of work
        pass
    return 0


__all__ = ["register", "run"]
