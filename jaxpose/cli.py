"""The ``jaxpose`` command: argument parsing and error reporting only.

Every subcommand lives in :mod:`jaxpose.commands` and registers itself.  Bad
input ends with one line ``jaxpose: error: <message>`` and exit status 2.
"""

from __future__ import annotations

import argparse
import importlib
import sys

from . import __version__
from .errors import JaxposeError

SUBCOMMANDS = ("fit", "render", "eval", "skeleton")


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="jaxpose",
        description="Pose of an arbitrary kinematic skeleton from a single depth image (evolutionary search in JAX).",
    )
    parser.add_argument("--version", action="version", version=f"jaxpose {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in SUBCOMMANDS:
        importlib.import_module(f"jaxpose.commands.{name}").register(sub)
    return parser


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except JaxposeError as e:
        print(f"jaxpose: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("jaxpose: interrupted; no output was written", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
