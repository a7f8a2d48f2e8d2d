"""The XLA settings the suite compiles with (tests/conftest.py applies them).

The suite is mostly the compilation of small searches, so it compiles with XLA:CPU's
quickest settings: LLVM's optimisation level 0 and, on the jaxlib versions jaxpose
uses it on (jaxpose/_xla_flags.py), the older fusion emitters.  They change the
machine code, not the operations: each computed value moves by float32 round-off at
most, though a search that branches on such a value may take another path
(docs/install.md, "Tests").  ``JAXPOSE_TEST_XLA=default`` keeps XLA's own settings.
"""

from __future__ import annotations

import os


def quick_options() -> list[str]:
    """The quick settings, as ``XLA_FLAGS`` options (an unknown debug option would abort XLA)."""
    quick = ["--xla_backend_optimization_level=0"]
    # jaxpose._xla_flags.fast_compile_options has the same window, but importing jaxpose computes
    # (and so starts JAX's backend) before these flags could be set
    try:
        from importlib.metadata import version

        if (0, 7) <= tuple(int(p) for p in version("jaxlib").split(".")[:2]) < (0, 11):
            quick.append("--xla_cpu_use_fusion_emitters=false")
    except Exception:  # noqa: BLE001 - no version to check: leave that option out
        pass
    return quick


def _name(option: str) -> str:
    return option.split("=")[0]


def with_quick(flags: str) -> str:
    """``flags`` (an ``XLA_FLAGS`` value) with the quick settings added where not already set."""
    if os.environ.get("JAXPOSE_TEST_XLA", "").strip().lower() == "default":
        return flags
    have = {_name(f) for f in flags.split()}
    return " ".join([flags] + [q for q in quick_options() if _name(q) not in have]).strip()


def without_quick(flags: str) -> str:
    """``flags`` with the quick settings taken out: XLA's defaults for the programs users run,
    where a test pins numbers to a tight tolerance (several devices against one)."""
    names = {_name(q) for q in quick_options()}
    return " ".join(f for f in flags.split() if _name(f) not in names)
