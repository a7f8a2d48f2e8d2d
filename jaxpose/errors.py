"""The exception types jaxpose raises for bad input.

Every error names the input (a file, an argument) and the problem in one line.
The command line turns them into ``jaxpose: error: <message>`` and exit status 2.
"""

from __future__ import annotations


class JaxposeError(ValueError):
    """Base class of every documented jaxpose input error."""


class SkeletonError(JaxposeError):
    """A skeleton file or skeleton description is invalid."""


class DepthError(JaxposeError):
    """A depth image, background image or point cloud cannot be used."""


class IntrinsicsError(JaxposeError):
    """Camera intrinsics are malformed or impossible."""


class ConfigError(JaxposeError):
    """A fit, render or experiment configuration is invalid."""


class InputWarning(UserWarning):
    """An input that can be fitted but probably not as meant (e.g. a cloud in the wrong unit).

    The command line prints it as ``jaxpose: warning: <message>``; a fit's result
    file lists it under ``warnings``."""


def require_finite(name: str, value) -> float:
    """``value`` as a float; :class:`ConfigError` ``"<name> must be a finite number"`` otherwise."""
    import numpy as np

    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not np.isfinite(value):
        raise ConfigError(f"{name} must be a finite number, got {value!r}")
    return float(value)


def require_integer(name: str, value, lo: int | None = None) -> int:
    """``value`` as an int (at least ``lo``); :class:`ConfigError` naming ``name`` otherwise."""
    import numpy as np

    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ConfigError(f"{name} must be an integer, got {value!r}")
    if lo is not None and value < lo:
        raise ConfigError(f"{name} must be >= {lo}, got {value}")
    return int(value)
