"""What the experiments print and write: progress lines, atomic files, number formats.

- :func:`log` (a flushed line), :func:`rel` (a path for messages);
- atomic outputs over :func:`jaxpose.io.atomic.atomic_write` (a killed run leaves no
  half-written file): :func:`write_json` (:func:`clean` first: NaN and infinities as
  null, a final newline), :func:`write_text`, :func:`write_csv`, :func:`save_figure`;
  :func:`pyplot` (matplotlib without a display);
- numbers in tables: :func:`fmt`, :func:`fmt_rate`.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
if ROOT not in sys.path:  # run as a script from anywhere without installing
    sys.path.insert(0, ROOT)

from jaxpose.io.atomic import atomic_write, to_jsonable  # noqa: E402


def log(msg: str = "") -> None:
    print(msg, flush=True)


def rel(path: str) -> str:
    """A path relative to the repository root when it lies inside it (for messages)."""
    p = os.path.relpath(os.path.abspath(path), ROOT)
    return path if p.startswith("..") else p


# --------------------------------------------------------------------------- atomic outputs


def clean(x):
    """JSON-ready (:func:`jaxpose.io.atomic.to_jsonable`), with NaN and infinities as null."""
    x = to_jsonable(x)
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, dict):
        return {k: clean(v) for k, v in x.items()}
    if isinstance(x, list):
        return [clean(v) for v in x]
    return x


def _ensure_dir(path: str) -> None:
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)


def write_text(path: str, text: str) -> None:
    _ensure_dir(path)
    atomic_write(path, lambda f: f.write(text))


def write_json(path: str, data) -> None:
    write_text(path, json.dumps(clean(data), indent=2, allow_nan=False) + "\n")


def write_csv(path: str, rows: list[dict], columns: list[str]) -> None:
    buf = io.StringIO()
    w = csv.DictWriter(buf, columns, extrasaction="ignore", lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: ("" if v is None else (f"{v:.6g}" if isinstance(v, float) else v))
                    for k, v in r.items()})
    write_text(path, buf.getvalue())


def pyplot():
    """``matplotlib.pyplot`` on the Agg backend (no display needed); ImportError without matplotlib."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig, path: str, dpi: int = 120) -> None:
    """Save a matplotlib figure atomically as PNG and close it."""
    import matplotlib.pyplot as plt

    _ensure_dir(path)
    try:
        atomic_write(path, lambda f: fig.savefig(f, format="png", dpi=dpi), binary=True)
    finally:
        plt.close(fig)


# --------------------------------------------------------------------------- numbers


def fmt(x, spec: str = ".3g", none: str = "-") -> str:
    return none if x is None else format(x, spec)


def fmt_rate(x) -> str:
    """A rate with a G / M / k suffix, three significant digits."""
    if x is None:
        return "-"
    for unit, scale in (("G", 1e9), ("M", 1e6), ("k", 1e3)):
        if x >= scale:
            return f"{x / scale:.3g}{unit}"
    return f"{x:.3g}"
