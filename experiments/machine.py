"""The machine, software and code a measurement comes from (every experiment records it).

- :func:`machine_info`: a JSON-ready record (CPU, cores, memory, platform, versions,
  backend and devices, ``XLA_FLAGS``, git commit, date);
- :func:`machine_id`: one short line for a fit record or a table caption;
- :func:`machine_line`: one long line from a stored :func:`machine_info` record;
- :func:`now_iso`, :func:`load_average`.
"""

from __future__ import annotations

import datetime
import os
import platform
import subprocess
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
if ROOT not in sys.path:  # run as a script from anywhere without installing
    sys.path.insert(0, ROOT)

import jax  # noqa: E402
import numpy as np  # noqa: E402

from jaxpose.io.fit_result import package_versions  # noqa: E402


def now_iso() -> str:
    """The time now, UTC, to the second (ISO 8601)."""
    return datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds")


def cpu_model() -> str:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.lower().startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    if sys.platform == "darwin":
        try:
            return subprocess.run(["sysctl", "-n", "machdep.cpu.brand_string"], capture_output=True, text=True,
                                  timeout=5).stdout.strip()
        except (OSError, subprocess.SubprocessError):
            pass
    return platform.processor() or platform.machine()


def usable_cores() -> int:
    """Cores this process may run on (its affinity), else all of them."""
    try:
        return len(os.sched_getaffinity(0))
    except (AttributeError, OSError):
        return os.cpu_count() or 1


def memory_gib() -> float | None:
    try:
        return round(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30, 1)
    except (ValueError, OSError, AttributeError):
        return None


def load_average() -> list[float] | None:
    """The 1, 5 and 15-minute load averages (None where the system has none)."""
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except OSError:
        return None


def git_commit() -> str | None:
    """The short commit of the working tree, ``+dirty`` when jaxpose/ or skeletons/ differ from it."""
    try:
        out = subprocess.run(["git", "-C", ROOT, "rev-parse", "--short", "HEAD"], capture_output=True, text=True,
                             timeout=10)
        dirty = subprocess.run(["git", "-C", ROOT, "status", "--porcelain", "--", "jaxpose", "skeletons"],
                               capture_output=True, text=True, timeout=10).stdout.strip()
        head = out.stdout.strip()
        return head + ("+dirty" if dirty else "") if out.returncode == 0 and head else None
    except (OSError, subprocess.SubprocessError):
        return None


def machine_id() -> str:
    """One line naming the machine a timing comes from."""
    dev = jax.devices()[0]
    acc = "" if dev.platform == "cpu" else f", {dev.device_kind}"
    return f"{cpu_model()}, {usable_cores()} cores, {jax.default_backend()}{acc}"


def machine_info(**extra) -> dict:
    """The machine and software, JSON-ready; ``extra`` entries (what a script adds) go before
    the git commit and the date."""
    versions = package_versions()
    return {
        "cpu": cpu_model(),
        "cores": os.cpu_count(),
        "cores_usable": usable_cores(),
        "memory_gib": memory_gib(),
        "platform": platform.platform(),
        "python": platform.python_version(),
        "numpy": np.__version__,
        "jax": jax.__version__,
        "jaxlib": versions.get("jaxlib"),
        "backend": jax.default_backend(),
        "devices": [f"{d.platform}:{d.device_kind}" for d in jax.devices()],
        "xla_flags": os.environ.get("XLA_FLAGS"),
        "versions": versions,
        **extra,
        "git": git_commit(),
        "date": now_iso(),
    }


def machine_line(m: dict) -> str:
    """One line describing a :func:`machine_info` record (for a report's header)."""
    return (f"{m['cpu']}, {m['cores_usable']} usable of {m['cores']} logical cores, {m['memory_gib']} GiB; "
            f"jax {m['jax']} (jaxlib {m['jaxlib']}), backend {m['backend']} ({', '.join(m['devices'])}); "
            f"numpy {m['numpy']}; Python {m['python']}")
