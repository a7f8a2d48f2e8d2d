"""The robot-file options: ``--max-capsules`` (``fit``, ``track``, ``render``, ``skeleton``),
``--search-lengths`` and ``--search-scale`` (``fit``, ``track``), and their record in result files."""

from __future__ import annotations

import os

MAX_CAPSULES_HELP = ("robot files (.urdf, MJCF): model each link by up to N capsules (one per geometry, plates and "
                     "disks cut into slabs; default 4; 1: one capsule per link)")


def add_max_capsules(p) -> None:
    p.add_argument("--max-capsules", type=int, default=None, metavar="N", help=MAX_CAPSULES_HELP)


def add_search_options(p) -> None:
    """``--search-lengths``, ``--search-scale`` and ``--max-capsules``."""
    p.add_argument("--search-lengths", action="store_true",
                   help="robot files (.urdf, MJCF): also search every link length within +-30%% (default: the model's)")
    p.add_argument("--search-scale", action="store_true",
                   help="robot files: search the global scale within 0.5-2 (default: held at 1, the robot's size)")
    add_max_capsules(p)


def check_search_options(args) -> None:
    """The robot-file options of ``fit`` and ``track``: each for robot files only, ``--search-scale``
    not with ``--scale`` (one :class:`~jaxpose.errors.ConfigError` otherwise)."""
    from ..errors import ConfigError

    check_max_capsules(args, args.skeleton)
    check_robot_option("--search-lengths", args.search_lengths, args.skeleton, "whose links set their own length_range")
    check_robot_option("--search-scale", args.search_scale, args.skeleton, "whose file sets its scale_range")
    if args.search_scale and args.scale is not None:
        raise ConfigError(f"--search-scale and --scale {args.scale:g}: give one (search the scale, or hold it at S)")


def robot_record(args, skel_file: str | None) -> dict:
    """The robot-file settings for a result's ``"skeleton"`` record (``max_capsules``: ``None``
    for a native skeleton)."""
    from ..io.capsules import MAX_CAPSULES
    from ..pipeline import robot_max_capsules

    capsules = MAX_CAPSULES if args.max_capsules is None else args.max_capsules
    return {"search_lengths": bool(args.search_lengths), "search_scale": bool(args.search_scale),
            "max_capsules": robot_max_capsules(skel_file, capsules, True)}


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
