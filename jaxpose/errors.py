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
