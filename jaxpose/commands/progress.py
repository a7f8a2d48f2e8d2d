"""A small terminal progress bar and output-path checks for the commands."""

from __future__ import annotations

import os
import sys
import tempfile
import time

from ..errors import ConfigError


class ProgressBar:
    """``generation/total, best cost, evaluations per second`` on one line of stderr.

    Silent when stderr is not a terminal or when ``quiet``.
    """

    def __init__(self, total: int, quiet: bool = False, stream=None, width: int = 30, label: str = ""):
        self.total = total
        self.label = label
        self.stream = stream or sys.stderr
        self.enabled = not quiet and hasattr(self.stream, "isatty") and self.stream.isatty()
        self.width = width
        self.t0 = time.perf_counter()
        self.shown = False

    def update(self, generation: int, best: float, evaluations: int) -> None:
        if not self.enabled:
            return
        dt = max(time.perf_counter() - self.t0, 1e-9)
        frac = min(generation / max(self.total, 1), 1.0)
        filled = int(frac * self.width)
        bar = "#" * filled + "-" * (self.width - filled)
        self.stream.write(
            f"\r{self.label}[{bar}] gen {generation}/{self.total}  best {best:.5f}  {evaluations / dt:,.0f} evals/s "
        )
        self.stream.flush()
        self.shown = True

    def close(self) -> None:
        if self.enabled and self.shown:
            self.stream.write("\n")
            self.stream.flush()


class FrameBar:
    """``[####----] frame 12/90  tracked  48.3 fps  (re-inits 0, lost 0)`` on one line of stderr;
    silent when stderr is not a terminal or when ``quiet``."""

    def __init__(self, total: int, quiet: bool = False, stream=None, width: int = 30):
        self.total, self.width = total, width
        self.stream = stream or sys.stderr
        self.enabled = not quiet and hasattr(self.stream, "isatty") and self.stream.isatty()
        self.shown = False

    def show(self, text: str, done: int) -> None:
        if not self.enabled:
            return
        filled = int(self.width * min(done / max(self.total, 1), 1.0))
        self.stream.write(f"\r[{'#' * filled}{'-' * (self.width - filled)}] {text}\x1b[K")
        self.stream.flush()
        self.shown = True

    def close(self) -> None:
        if self.enabled and self.shown:
            self.stream.write("\n")
            self.stream.flush()


def check_output_path(path: str, what: str) -> None:
    """Fail early (before any work) when an output cannot be written.

    Besides the permission bits, a temporary file is created and removed in the
    folder, which also catches read-only file systems (and works for root).
    """
    d = os.path.dirname(os.path.abspath(path)) or "."
    shown = os.path.dirname(path) or "."
    if not os.path.isdir(d):
        raise ConfigError(f"{what} {path}: directory {shown} does not exist")
    if os.path.isdir(path):
        raise ConfigError(f"{what} {path}: is a directory")
    if not os.access(d, os.W_OK):
        raise ConfigError(f"{what} {path}: directory {shown} is not writable")
    try:
        with tempfile.TemporaryFile(dir=d, prefix=".jaxpose-probe-"):
            pass
    except OSError as e:
        raise ConfigError(f"{what} {path}: directory {shown} is not writable ({e.strerror or e})") from None
