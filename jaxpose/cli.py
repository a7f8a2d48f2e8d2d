"""The ``jaxpose`` command: argument parsing and error reporting only.

Every subcommand lives in :mod:`jaxpose.commands` and registers itself.  Bad
input (a documented :class:`~jaxpose.errors.JaxposeError`, or arguments the
parser rejects) ends with one line ``jaxpose: error: <message>`` on stderr and
exit status 2; an operating-system error while reading or writing a file ends
with one such line and status 1; Ctrl-C with one line and status 130; a closed
output pipe (``| head``) quietly with status 141, as a shell's tools do.  The
messages are listed in docs/errors.md.
"""

from __future__ import annotations

import argparse
import importlib
import os
import pkgutil
import sys

from . import __version__
from .errors import JaxposeError

# The order of ``jaxpose --help``; a module of jaxpose.commands with a ``register``
# function is a subcommand, so a new command is one new file.
_HELP_ORDER = ("fit", "track", "render", "eval", "view", "skeleton")


def _subcommands() -> tuple[str, ...]:
    from . import commands

    found = [m.name for m in pkgutil.iter_modules(commands.__path__)
             if hasattr(importlib.import_module(f"jaxpose.commands.{m.name}"), "register")]
    rank = {name: i for i, name in enumerate(_HELP_ORDER)}
    return tuple(sorted(found, key=lambda n: (rank.get(n, len(rank)), n)))



class _Parser(argparse.ArgumentParser):
    """An argument parser whose errors are one line: ``jaxpose: error: <message> (see ... --help)``."""

    def error(self, message):  # noqa: D401 - argparse API
        if message.endswith("expected one argument"):
            flag = message.split(":")[0].replace("argument ", "").split("/")[-1].strip()
            message += f" (write {flag}=VALUE when the value starts with '-')"
        self.exit(2, f"jaxpose: error: {message} (see '{self.prog} --help')\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="jaxpose",
        description="Pose of an arbitrary kinematic skeleton from a single depth image or point cloud "
                    "(evolutionary search in JAX).",
    )
    parser.add_argument("--version", action="version", version=f"jaxpose {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in _subcommands():
        importlib.import_module(f"jaxpose.commands.{name}").register(sub)
    return parser


def enable_compilation_cache() -> str | None:
    """Keep XLA's compiled programs on disk between runs: the first fit of a
    configuration compiles for seconds, later runs load it.  Every program is kept,
    also the quick ones (a fit has many; docs/performance.md, "Cold fits, the compile
    cache and batches").

    ``JAXPOSE_CACHE_DIR`` names the folder (default ``$XDG_CACHE_HOME/jaxpose/xla``
    or ``~/.cache/jaxpose/xla``); ``JAXPOSE_CACHE_DIR=0`` turns the cache off.  A
    folder that cannot be created just means no cache.  Returns the folder used.
    """
    d = os.environ.get("JAXPOSE_CACHE_DIR")
    if d is not None and d.strip() in ("", "0"):
        return None
    if d is None:
        base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
        d = os.path.join(base, "jaxpose", "xla")
    try:
        os.makedirs(d, exist_ok=True)
        import jax

        jax.config.update("jax_compilation_cache_dir", d)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    except (OSError, AttributeError, ValueError):
        return None
    return d


def main(argv=None) -> int:
    """Run the command line with ``argv`` (default ``sys.argv[1:]``); return the exit status."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as e:  # --help, --version, or a parser error already printed
        return e.code if isinstance(e.code, int) else (0 if e.code is None else 2)
    if not getattr(args, "func", None):
        parser.print_help()
        print(f"jaxpose: error: no command given (one of {', '.join(_subcommands())})", file=sys.stderr)
        return 2
    enable_compilation_cache()
    try:
        return int(args.func(args) or 0)
    except JaxposeError as e:
        print(f"jaxpose: error: {one_line(e)}", file=sys.stderr)
        return 2
    except BrokenPipeError:  # `jaxpose eval ... | head`: the reader has gone, nothing to report
        sys.stdout = open(os.devnull, "w")  # noqa: SIM115 - no flush of the dead pipe at exit
        return 141
    except OSError as e:  # e.g. a disk that fills up while writing
        where = f"{e.filename}: " if getattr(e, "filename", None) else ""
        print(f"jaxpose: error: {where}{e.strerror or one_line(e)}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("jaxpose: interrupted (no partially written output file is left behind)", file=sys.stderr)
        return 130


def one_line(e: BaseException) -> str:
    """An error's message on one line (what ``jaxpose: error:`` prints)."""
    return " ".join(str(e).split()) or e.__class__.__name__


if __name__ == "__main__":
    sys.exit(main())
