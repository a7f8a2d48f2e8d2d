"""Native skeleton files (TOML or JSON) and the dispatcher for robot formats.

Schema (TOML shown; JSON uses the same keys)::

    name = "spider"              # optional, default: the file name
    scale_range = [0.5, 2.0]     # optional, search range of the global scale

    [[link]]
    name = "leg0_upper"          # unique
    parent = "..."               # optional; omitted: the link hangs from the root frame
    joint = "ball"               # ball (3 DOF) | hinge (1 DOF) | fixed (0 DOF)
    offset = [0.06, 0.06, 0.0]   # anchor in the parent frame, metres (default 0)
    attach = 1.0                 # fraction of the parent's length added to the anchor
                                 # (default 1 with a parent: its far end; 0 without)
    rest = [0, 0, 45]            # rest rotation roll, pitch, yaw, degrees (default 0)
    axis = [0, 1, 0]             # hinge axis in the rest frame (hinge only)
    limits = [[-30, 30], [-60, 60], [-45, 45]]  # degrees; ball: 3 pairs, hinge: 1
    length = 0.15                # metres, > 0; the link points along its +x axis
    length_range = [0.1, 0.2]    # optional: search the length (default: fixed)
    radius = 0.02                # capsule radius, metres (0: a line segment)
"""

from __future__ import annotations

import json
import os
import tomllib

from ..errors import SkeletonError
from ..skeleton import LinkSpec, Skeleton, build_skeleton

MAX_SKELETON_BYTES = 16 * 1024 * 1024
_LINK_KEYS = {
    "name", "parent", "joint", "offset", "attach", "rest", "axis", "limits", "length", "length_range", "radius",
}


def _shipped_path(name: str) -> str | None:
    here = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    for base in (os.path.join(here, "skeletons"), os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "skeletons")):
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


def load_skeleton(path: str) -> Skeleton:
    """Read a skeleton from a native ``.toml``/``.json`` file, a ``.urdf`` or an MJCF ``.xml``.

    A bare name such as ``"spider"`` loads the shipped skeleton of that name.
    Raises :class:`~jaxpose.errors.SkeletonError` naming the file and the problem.
    """
    path = resolve_skeleton_path(str(path))
    if not os.path.exists(path):
        raise SkeletonError(f"{path}: skeleton file not found")
    if os.path.isdir(path):
        raise SkeletonError(f"{path}: is a directory, not a skeleton file")
    size = os.path.getsize(path)
    if size > MAX_SKELETON_BYTES:
        raise SkeletonError(f"{path}: file is {size} bytes, more than the {MAX_SKELETON_BYTES} allowed for a skeleton")
    ext = os.path.splitext(path)[1].lower()
    if ext == ".urdf":
        from .urdf import load_urdf

        return load_urdf(path)
    if ext in (".xml", ".mjcf"):
        from .mjcf import load_mjcf

        return load_mjcf(path)
    try:
        with open(path, "rb") as f:
            raw = f.read()
        text = raw.decode("utf-8")
    except (OSError, UnicodeDecodeError) as e:
        raise SkeletonError(f"{path}: cannot read skeleton file ({e.__class__.__name__}: {e})") from None
    if not text.strip():
        raise SkeletonError(f"{path}: the skeleton file is empty")
    try:
        data = json.loads(text) if ext == ".json" else tomllib.loads(text)
    except (json.JSONDecodeError, tomllib.TOMLDecodeError) as e:
        kind = "JSON" if ext == ".json" else "TOML"
        raise SkeletonError(f"{path}: not valid {kind}: {e}") from None
    default_name = os.path.splitext(os.path.basename(path))[0]
    return skeleton_from_dict(data, source=path, default_name=default_name)


def skeleton_from_dict(data, source: str = "<skeleton>", default_name: str = "skeleton") -> Skeleton:
    """Build a skeleton from the parsed native schema (see the module docstring)."""
    if not isinstance(data, dict):
        raise SkeletonError(f"{source}: expected a table/object at the top level")
    links = data.get("link", data.get("links"))
    if links is None or links == []:
        raise SkeletonError(f"{source}: the skeleton has no links (expected [[link]] entries)")
    if not isinstance(links, list):
        raise SkeletonError(f"{source}: 'link' must be a list of tables")
    specs = []
    for k, item in enumerate(links):
        if not isinstance(item, dict):
            raise SkeletonError(f"{source}: link #{k + 1} is not a table")
        name = item.get("name")
        if not isinstance(name, str) or not name:
            raise SkeletonError(f"{source}: link #{k + 1} needs a non-empty string 'name'")
        unknown = set(item) - _LINK_KEYS
        if unknown:
            raise SkeletonError(f"{source}: link {name!r}: unknown key(s) {', '.join(sorted(unknown))}")
        parent = item.get("parent")
        if parent is not None and not isinstance(parent, str):
            raise SkeletonError(f"{source}: link {name!r}: 'parent' must be a link name")
        kw = {key: item[key] for key in item if key not in ("name", "parent")}
        if "joint" in kw and not isinstance(kw["joint"], str):
            raise SkeletonError(f"{source}: link {name!r}: 'joint' must be a string")
        specs.append(LinkSpec(name=name, parent=parent or None, **kw))
    scale_range = data.get("scale_range", (0.5, 2.0))
    return build_skeleton(str(data.get("name", default_name)), specs, scale_range=scale_range, source=source)


def shipped_skeletons() -> list[str]:
    """Names of the skeletons shipped in ``skeletons/``."""
    p = _shipped_path("spider")
    if p is None:
        return []
    d = os.path.dirname(p)
    return sorted(os.path.splitext(f)[0] for f in os.listdir(d) if f.endswith(".toml"))
