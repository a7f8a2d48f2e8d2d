"""``make demo``: fit the spider to the bundled depth image and score it.

Runs ``jaxpose fit`` on ``jaxpose/data/spider_demo.png`` (background subtracted
with the bundled background image), writes ``result.json`` and ``overlay.png``
to ``--out`` and prints the link accuracy against the bundled ground truth.
"""

from __future__ import annotations

import argparse
import os
import sys

DATA = os.path.join(os.path.dirname(os.path.abspath(__file__)), "data")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m jaxpose.demo", description=__doc__)
    ap.add_argument("--out", default="out/demo", help="output folder (default out/demo)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--quiet", action="store_true")
    args = ap.parse_args(argv)
    os.makedirs(args.out, exist_ok=True)
    from .cli import main as cli_main

    result = os.path.join(args.out, "result.json")
    plot = os.path.join(args.out, "overlay.png")
    fit_args = ["fit", os.path.join(DATA, "spider_demo.png"), "--skeleton", "spider",
                "--background", os.path.join(DATA, "spider_demo_background.png"),
                "--seed", str(args.seed), "--out", result]
    try:
        import matplotlib  # noqa: F401

        fit_args += ["--plot", plot]
    except ImportError:
        print("jaxpose demo: matplotlib is not installed (pip install 'jaxpose[viz]'); no overlay plot")
    rc = cli_main(fit_args + (["--quiet"] if args.quiet else []))
    if rc:
        return rc
    print("accuracy against the bundled ground truth (jaxpose eval):")
    return cli_main(["eval", result, os.path.join(DATA, "spider_demo_truth.json"), "--skeleton", "spider"])


if __name__ == "__main__":
    sys.exit(main())
