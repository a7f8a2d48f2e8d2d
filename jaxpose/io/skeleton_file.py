"""Native skeleton files (TOML or JSON) and the dispatcher for robot formats.

Schema (TOML shown; JSON uses the same keys)::

    name = "spider"              # optional, default: the file name
    scale_range = [0.5, 2.0]     # optional, search range of the global scale

    [[link]]
    name = "leg0_upper"          # unique
    parent = "..."               # optional; omitted: the link hangs from the root frame
    joint = "ball"               # ball (3 DOF) | hinge (1 DOF) | slide (1 DOF) | fixed (0 DOF)
    offset = [0.06, 0.06, 0.0]   # anchor in the parent frame, metres (default 0)
    attach = 1.0                 # fraction of the parent's length added to the anchor
                                 # (default 1 with a parent: its far end; 0 without)
    rest = [0, 0, 45]            # rest rotation roll, pitch, yaw, degrees (default 0)
    axis = [0, 1, 0]             # hinge / slide axis in the rest frame (hinge, slide only)
    limits = [[-30, 30], [-60, 60], [-45, 45]]  # degrees; ball: 3 pairs, hinge: 1; slide: 1, metres
    length = 0.15                # metres, > 0; the link points along its +x axis
    length_range = [0.1, 0.2]    # optional: search the length (default: fixed)
    radius = 0.02                # capsule radius, metres (0: a line segment)
"""

from __future__ import annotations

import json
import math
import os
import tomllib

from ..errors import SkeletonError
from ..skeleton import LinkSpec, Skeleton, build_skeleton

MAX_SKELETON_BYTES = 16 * 1024 * 1024
MAX_LINKS = 4096
_TOP_KEYS = {"name", "description", "scale_range", "link", "links"}
_LINK_KEYS = {
    "name", "parent", "joint", "offset", "attach", "rest", "axis", "limits", "length", "length_range", "radius",
}


def _shipped_path(name: str) -> str | None:
    here = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    package_dir = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    for base in (os.path.join(here, "skeletons"), os.path.join(package_dir, "skeletons")):
        p = os.path.join(base, f"{name}.toml")
        if os.path.isfile(p):
            return p
    return None


def resolve_skeleton_path(path: str) -> str:
    """A file path, or the name of a shipped skeleton (``spider``, ``humanoid``, ...)."""
    if not os.path.exists(path) and os.sep not in path and "." not in path:
        shipped = _shipped_path(path)
        if shipped:
            return shipped
    return path


URDF_EXTENSIONS = (".urdf",)
MJCF_EXTENSIONS = (".xml", ".mjcf")
ROBOT_EXTENSIONS = URDF_EXTENSIONS + MJCF_EXTENSIONS  # robot files: lengths fixed unless searched


def load_skeleton(path: str, search_lengths: bool = False, max_capsules: int | None = None,
                  search_scale: bool = False) -> Skeleton:
    """Read a skeleton from a native ``.toml``/``.json`` file, a ``.urdf`` or an MJCF ``.xml``.

    A bare name such as ``"spider"`` loads the shipped skeleton of that name.
    ``search_lengths`` (robot files only) searches every capsule length within
    +-30 % instead of keeping the model's; a native file declares ``length_range``
    per link instead.  Raises :class:`~jaxpose.errors.SkeletonError` naming the file
    and the problem.  ``max_capsules`` (robot files only): capsules per link at most
    (:func:`~jaxpose.io.capsules.link_capsules`; default :data:`~jaxpose.io.capsules.MAX_CAPSULES`).
    A robot file's global scale is held at 1 (its robot's size) unless ``search_scale``
    (robot files only), which searches it within
    :data:`~jaxpose.io.capsules.SEARCHED_SCALE_RANGE`; a native file declares ``scale_range``.
    """
    given = str(path)
    path = resolve_skeleton_path(given)
    if not os.path.exists(path):
        if os.sep not in given and "." not in given:
            names = ", ".join(shipped_skeletons())
            raise SkeletonError(f"{given}: no such skeleton file, and not a shipped skeleton ({names})")
        raise SkeletonError(f"{path}: skeleton file not found")
    if os.path.isdir(path):
        raise SkeletonError(f"{path}: is a directory, not a skeleton file")
    if not os.path.isfile(path):
        raise SkeletonError(f"{path}: not a regular file")
    size = os.path.getsize(path)
    if size > MAX_SKELETON_BYTES:
        raise SkeletonError(f"{path}: file is {size} bytes, more than the {MAX_SKELETON_BYTES} allowed for a skeleton")
    ext = os.path.splitext(path)[1].lower()
    if max_capsules is not None:
        from .capsules import check_max_capsules

        max_capsules = check_max_capsules(max_capsules, path)
    robot = {} if max_capsules is None else {"max_capsules": max_capsules}
    if search_scale:
        from .capsules import SEARCHED_SCALE_RANGE

        robot["scale_range"] = SEARCHED_SCALE_RANGE
    if ext in URDF_EXTENSIONS:
        from .urdf import load_urdf

        return load_urdf(path, search_lengths=search_lengths, **robot)
    if ext in MJCF_EXTENSIONS:
        from .mjcf import load_mjcf

        return load_mjcf(path, search_lengths=search_lengths, **robot)
    if search_scale:
        raise SkeletonError(f"{path}: searching the scale is an option for robot files (.urdf, MJCF .xml); "
                            "a native skeleton file sets scale_range instead")
    if search_lengths:
        raise SkeletonError(f"{path}: searching lengths is an option for robot files (.urdf, MJCF .xml); "
                            "a native skeleton file sets each link's length_range instead")
    if max_capsules is not None and max_capsules != 1:
        raise SkeletonError(f"{path}: several capsules per link is an option for robot files (.urdf, MJCF .xml); "
                            "a native skeleton file's links are one capsule each")
    try:
        with open(path, "rb") as f:
            raw = f.read(MAX_SKELETON_BYTES + 1)
    except OSError as e:
        raise SkeletonError(f"{path}: cannot read skeleton file ({e.strerror or e})") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as e:
        raise SkeletonError(f"{path}: not a UTF-8 text file (byte {raw[e.start]:#04x} at offset {e.start})") from None
    if len(raw) > MAX_SKELETON_BYTES:
        raise SkeletonError(f"{path}: more than the {MAX_SKELETON_BYTES} bytes allowed for a skeleton")
    if not text.strip():
        raise SkeletonError(f"{path}: the skeleton file is empty")
    kind = "JSON" if ext == ".json" else "TOML"
    try:
        data = json.loads(text) if ext == ".json" else tomllib.loads(text)
    except (ValueError, RecursionError) as e:  # JSONDecodeError and TOMLDecodeError are ValueErrors
        reason = "nested too deeply" if isinstance(e, RecursionError) else " ".join(str(e).split())
        raise SkeletonError(f"{path}: not valid {kind}: {reason}") from None
    default_name = os.path.splitext(os.path.basename(path))[0]
    return skeleton_from_dict(data, source=path, default_name=default_name)


def _key(k) -> str:
    """A key as written, quoted when it is empty or not plain printable text."""
    return k if isinstance(k, str) and k and k.isprintable() and k.strip() == k else repr(k)


def _is_number(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _check_numbers(value, where: str, depth: int = 0) -> None:
    """Reject integers too large for a float and absurdly nested values (JSON allows both)."""
    if depth > 8:
        raise SkeletonError(f"{where}: values are nested too deeply")
    if isinstance(value, int) and not isinstance(value, bool) and abs(value) > 2**63:
        raise SkeletonError(f"{where}: number {str(value)[:20]}... is too large")
    if isinstance(value, list):
        for v in value:
            _check_numbers(v, where, depth + 1)
    elif isinstance(value, dict):
        for v in value.values():
            _check_numbers(v, where, depth + 1)


def skeleton_from_dict(data, source: str = "<skeleton>", default_name: str = "skeleton") -> Skeleton:
    """Build a skeleton from the parsed native schema (see the module docstring).

    Raises :class:`~jaxpose.errors.SkeletonError` naming ``source``, the link and the problem.
    """
    if not isinstance(data, dict):
        raise SkeletonError(f"{source}: expected a table/object at the top level")
    unknown = [_key(k) for k in data if k not in _TOP_KEYS]
    if unknown:
        raise SkeletonError(
            f"{source}: unknown top-level key(s) {', '.join(sorted(unknown))} (expected name, scale_range, [[link]])"
        )
    links = data.get("link", data.get("links"))
    if links is None or links == []:
        raise SkeletonError(f"{source}: the skeleton has no links (expected [[link]] entries)")
    if not isinstance(links, list):
        raise SkeletonError(f"{source}: 'link' must be a list of tables")
    if len(links) > MAX_LINKS:
        raise SkeletonError(f"{source}: {len(links)} links, more than the {MAX_LINKS} supported")
    name = data.get("name", default_name)
    if not isinstance(name, str) or not name.strip():
        raise SkeletonError(f"{source}: 'name' must be a non-empty string, got {name!r:.40}")
    specs = []
    for k, item in enumerate(links):
        if not isinstance(item, dict):
            raise SkeletonError(f"{source}: link #{k + 1} is not a table")
        lname = item.get("name")
        if not isinstance(lname, str) or not lname:
            raise SkeletonError(f"{source}: link #{k + 1} needs a non-empty string 'name'")
        unknown = [_key(key) for key in item if key not in _LINK_KEYS]
        if unknown:
            raise SkeletonError(f"{source}: link {lname!r}: unknown key(s) {', '.join(sorted(unknown))}")
        _check_numbers(item, f"{source}: link {lname!r}")
        parent = item.get("parent")
        if parent is not None and not isinstance(parent, str):
            raise SkeletonError(f"{source}: link {lname!r}: 'parent' must be a link name")
        kw = {key: item[key] for key in item if key not in ("name", "parent")}
        if "joint" in kw and not isinstance(kw["joint"], str):
            raise SkeletonError(f"{source}: link {lname!r}: 'joint' must be a string")
        if "attach" in kw and not (_is_number(kw["attach"]) and math.isfinite(kw["attach"])):
            raise SkeletonError(f"{source}: link {lname!r}: 'attach' must be a finite number, got {kw['attach']!r:.40}")
        specs.append(LinkSpec(name=lname, parent=parent or None, **kw))
    scale_range = data.get("scale_range", (0.5, 2.0))
    _check_numbers(scale_range, f"{source}: scale_range")
    return build_skeleton(name, specs, scale_range=scale_range, source=source)


def shipped_skeletons() -> list[str]:
    """Names of the skeletons shipped in ``skeletons/``."""
    p = _shipped_path("spider")
    if p is None:
        return []
    d = os.path.dirname(p)
    return sorted(os.path.splitext(f)[0] for f in os.listdir(d) if f.endswith(".toml"))
