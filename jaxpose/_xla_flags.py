"""A workaround for a crash in XLA:CPU, applied when :mod:`jaxpose` is imported.

jaxlib 0.10's CPU backend hands element-wise and reduction fusions to YNNPACK
(``--xla_cpu_experimental_ynn_fusion_type``).  On the nested batching of the
search (islands x memetic refinement of the best individuals, e.g. 8 x 8, the
defaults) one of those fusions segfaults inside YNNPACK's transpose.  Without
YNNPACK fusions the same programs run correctly, at the same objective throughput
(``experiments/bench.py`` measures both).

XLA reads ``XLA_FLAGS`` when JAX creates its first backend, so the flag only takes
effect if jaxpose is imported before JAX computes anything.  A user who sets the
option in ``XLA_FLAGS`` (to any value) keeps their own setting.
"""

from __future__ import annotations

import os
import warnings

FLAG = "--xla_cpu_experimental_ynn_fusion_type"


def _jaxlib_version() -> tuple[int, ...]:
    try:
        import jaxlib

        return tuple(int(p) for p in jaxlib.__version__.split(".")[:2])
    except Exception:  # noqa: BLE001 - an unknown version: leave the flags alone
        return (0,)


def _backend_started() -> bool:
    try:
        from jax._src import xla_bridge

        return bool(getattr(xla_bridge, "_backends", {}))
    except Exception:  # noqa: BLE001 - private API moved: assume not started
        return False


def disable_ynn_fusions() -> bool:
    """Add ``FLAG=`` (no YNNPACK fusions) to ``XLA_FLAGS`` unless already set.

    Returns whether the flag is in force for this process's CPU backend.
    """
    flags = os.environ.get("XLA_FLAGS", "")
    if FLAG in flags:
        return True
    if _jaxlib_version() < (0, 10):  # older XLA does not know the flag (and would abort on it)
        return False
    if _backend_started():
        warnings.warn(
            "jaxpose: JAX's CPU backend started before jaxpose was imported, so XLA's YNNPACK fusions stay on; "
            "they crash (segfault) on jaxlib 0.10 in the search's refinement step. Import jaxpose first, or set "
            f"XLA_FLAGS='{FLAG}=' before starting Python.",
            RuntimeWarning,
            stacklevel=3,
        )
        return False
    os.environ["XLA_FLAGS"] = f"{flags} {FLAG}=".strip()
    return True


# XLA:CPU's newer MLIR fusion emitters generate faster code for some loops but take
# longer to compile.  The programs that run once or a few times per fit (the initial
# population, the gradient refinement, the write-back and the result) compile faster
# with the older emitters at the same speed and numbers up to float32 round-off; the
# generation loop, most of a fit's run time, keeps the default, which runs it faster
# (docs/performance.md, "Compile time").
# ``xla_cpu_use_fusion_emitters`` is an XLA debug option: used only on the jaxlib
# versions it was checked on, since an unknown option is an error at compile time.
_FAST_COMPILE = {"xla_cpu_use_fusion_emitters": False}


def fast_compile_options() -> dict | None:
    """``compiler_options`` for programs where compile time matters more than run
    time (``None`` where the option is not known to exist)."""
    return dict(_FAST_COMPILE) if (0, 7) <= _jaxlib_version() < (0, 11) else None
