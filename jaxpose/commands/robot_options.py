"""The robot-file options shared by ``fit``, ``render`` and ``skeleton``: ``--max-capsules``."""

from __future__ import annotations

import os

MAX_CAPSULES_HELP = ("robot files (.urdf, MJCF): model each link by up to N capsules (one per geometry, plates and "
                     "disks cut into slabs; default 4; 1: one capsule per link)")


def add_max_capsules(p) -> None:
    p.add_argument("--max-capsules", type=int, default=None, metavar="N", help=MAX_CAPSULES_HELP)


def check_robot_option(flag: str, given: bool, skeleton: str, native: str) -> None:
    """One :class:`~jaxpose.errors.ConfigError` when ``flag`` was ``given`` for a native skeleton
    (``native``: why it has no use there)."""
    if not given:
        return
    from ..errors import ConfigError
    from ..io.skeleton_file import ROBOT_EXTENSIONS, resolve_skeleton_path

    if os.path.splitext(resolve_skeleton_path(skeleton))[1].lower() not in ROBOT_EXTENSIONS:
        raise ConfigError(f"{flag}: only for robot files (.urdf, MJCF .xml); {skeleton} is a native skeleton, {native}")


def check_max_capsules(args, skeleton: str) -> None:
    """``--max-capsules``: at least 1, and for robot files only (one clear error otherwise)."""
    from ..errors import ConfigError

    if args.max_capsules is not None and args.max_capsules < 1:
        raise ConfigError(f"--max-capsules: must be at least 1, got {args.max_capsules}")
    check_robot_option("--max-capsules", args.max_capsules is not None, skeleton, "whose links are one capsule each")
