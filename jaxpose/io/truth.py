"""Ground-truth files of synthetic images, and reading link end points and poses back.

A truth file is JSON::

    {
      "format": "jaxpose-truth", "version": 1,
      "skeleton": {"name": "spider", "file": "skeletons/spider.toml"},
      "links": [{"name", "parent" (name or null), "start": [x, y, z], "end": [x, y, z],
                 "radius", "visible"}, ...],        # camera frame, metres
      "params": {"root_translation", "root_rpy", "scale",           # camera frame, radians,
                 "joints": {link: [angles]}, "lengths": {link: m}},  # as in the fit's result
      "params_world": {...},                        # the same pose in the skeleton's frame
      "camera": {"intrinsics": {"fx", "fy", "cx", "cy", "width", "height"},
                 "T_cam_world": 4x4 (world -> camera), ...},
      "image": "...png", "background": "...png" or null, "sensor": {...} or null, "meta": {...}
    }

``links`` has the shape of the fit command's result file, so that
:func:`read_links` reads both and ``jaxpose eval`` can compare any two.
"""

from __future__ import annotations

import dataclasses
import json
import os
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from ..errors import JaxposeError
from ..skeleton import JOINT_DOF, Pose, Skeleton
from .atomic import write_json
from .depth_file import save_depth_png


class TruthError(JaxposeError):
    """A truth or result file is missing, malformed or does not fit the skeleton."""


class LinkSet(NamedTuple):
    """Link end points read from a truth or result file (camera frame, metres)."""

    names: tuple[str, ...]
    parents: tuple[str | None, ...]
    start: np.ndarray  # (L, 3)
    end: np.ndarray  # (L, 3)
    skeleton_name: str | None
    skeleton_file: str | None


def pose_dict(skel: Skeleton, pose: Pose) -> dict:
    """A pose as JSON, in the schema of the fit command's ``params`` (joints and lengths by link name)."""
    angles = np.asarray(pose.angles, np.float64)
    lengths = np.asarray(pose.lengths, np.float64)
    return {
        "root_translation": np.asarray(pose.root_t, np.float64).tolist(),
        "root_rpy": np.asarray(pose.root_rpy, np.float64).tolist(),
        "scale": float(pose.scale),
        "joints": {n: angles[i, : JOINT_DOF[j]].tolist()
                   for i, (n, j) in enumerate(zip(skel.link_names, skel.joint_types))},
        "lengths": {n: float(lengths[i]) for i, n in enumerate(skel.link_names)},
    }


def truth_dict(skel: Skeleton, view, skeleton_file: str | None = None, image: str | None = None,
               background: str | None = None, sensor=None, meta: dict | None = None) -> dict:
    """The truth record of a :class:`~jaxpose.datasets.View` (see the module docstring)."""
    k = view.intrinsics
    links = []
    for i, name in enumerate(skel.link_names):
        p = skel.parents[i]
        links.append({
            "name": name,
            "parent": skel.link_names[p] if p >= 0 else None,
            "start": np.asarray(view.start[i], np.float64).tolist(),
            "end": np.asarray(view.end[i], np.float64).tolist(),
            "radius": float(view.radius[i]),
            "visible": float(view.visible[i]),
        })
    return {
        "format": "jaxpose-truth",
        "version": 1,
        "skeleton": {"name": skel.name, "file": skeleton_file},
        "links": links,
        "params": pose_dict(skel, view.pose),
        "params_world": pose_dict(skel, view.pose_world),
        "camera": {
            "intrinsics": {"fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy, "width": k.width, "height": k.height},
            "T_cam_world": np.asarray(view.T_cam_world, np.float64).tolist(),
        },
        "image": image,
        "background": background,
        "sensor": dataclasses.asdict(sensor) if sensor is not None else None,
        "meta": meta or {},
    }


def write_view(depth_path: str, truth_path: str, skel: Skeleton, view, background_path: str | None = None,
               skeleton_file: str | None = None, sensor=None, meta: dict | None = None) -> dict:
    """Write the depth PNG (millimetres), the optional background PNG and the truth JSON, atomically.

    Paths stored in the truth file are relative to the truth file's folder.
    """
    for p in (depth_path, truth_path, background_path):
        if p is not None:
            d = os.path.dirname(os.path.abspath(p))
            if not os.path.isdir(d):
                raise TruthError(f"{p}: folder {os.path.dirname(p) or '.'} does not exist")
    save_depth_png(depth_path, view.depth)
    if background_path is not None:
        if view.background is None:
            raise TruthError(f"{background_path}: there is no background to write (no floor or clutter rendered)")
        save_depth_png(background_path, view.background)
    here = os.path.dirname(os.path.abspath(truth_path))
    rel = lambda p: None if p is None else os.path.relpath(os.path.abspath(p), here)  # noqa: E731
    truth = truth_dict(skel, view, skeleton_file, rel(depth_path), rel(background_path), sensor, meta)
    write_json(truth_path, truth)
    return truth


def _load_json(path: str) -> dict:
    path = str(path)
    if not os.path.exists(path):
        raise TruthError(f"{path}: file not found")
    try:
        with open(path) as f:
            data = json.load(f)
    except (OSError, json.JSONDecodeError, UnicodeDecodeError) as e:
        raise TruthError(f"{path}: not valid JSON ({e})") from None
    if not isinstance(data, dict):
        raise TruthError(f"{path}: expected a JSON object at the top level")
    return data


def read_links(path: str) -> LinkSet:
    """Read ``links`` (name, parent, start, end) and ``skeleton`` from a truth or result file."""
    data = _load_json(path)
    links = data.get("links")
    if not isinstance(links, list) or not links:
        raise TruthError(f"{path}: needs a non-empty 'links' list of {{name, parent, start, end}}")
    names, parents, start, end = [], [], [], []
    for n, item in enumerate(links):
        if not isinstance(item, dict) or not isinstance(item.get("name"), str):
            raise TruthError(f"{path}: link #{n + 1} needs a string 'name'")
        try:
            s = np.asarray(item["start"], np.float64).reshape(3)
            e = np.asarray(item["end"], np.float64).reshape(3)
        except (KeyError, TypeError, ValueError):
            raise TruthError(f"{path}: link {item['name']!r}: 'start' and 'end' must be 3 numbers each") from None
        if not (np.all(np.isfinite(s)) and np.all(np.isfinite(e))):
            raise TruthError(f"{path}: link {item['name']!r}: end points must be finite")
        if item["name"] in names:
            raise TruthError(f"{path}: duplicate link {item['name']!r}")
        names.append(item["name"])
        parent = item.get("parent")
        parents.append(parent if isinstance(parent, str) else None)
        start.append(s)
        end.append(e)
    sk = data.get("skeleton") if isinstance(data.get("skeleton"), dict) else {}
    return LinkSet(tuple(names), tuple(parents), np.array(start), np.array(end),
                   sk.get("name") if isinstance(sk.get("name"), str) else None,
                   sk.get("file") if isinstance(sk.get("file"), str) else None)


def read_pose(path: str, skel: Skeleton, world: bool = False) -> Pose:
    """The pose stored in a truth or result file (``params``, or ``params_world`` with ``world``)."""
    data = _load_json(path)
    key = "params_world" if world else "params"
    p = data.get(key)
    if not isinstance(p, dict):
        raise TruthError(f"{path}: has no {key!r} object with the pose")
    L = skel.num_links

    def num(value, what, shape):
        try:
            a = np.asarray(value, np.float64)
        except (TypeError, ValueError):
            a = None
        if a is None or a.shape != shape or not np.all(np.isfinite(a)):
            raise TruthError(f"{path}: {key}.{what} must be finite numbers of shape {shape}, got {value!r:.60}")
        return a

    for f in ("root_translation", "root_rpy", "scale", "joints", "lengths"):
        if f not in p:
            raise TruthError(f"{path}: {key}.{f} is missing")
    joints, lens = p["joints"], p["lengths"]
    if not isinstance(joints, dict) or not isinstance(lens, dict):
        raise TruthError(f"{path}: {key}.joints and {key}.lengths must map link names to values")
    missing = [n for n in skel.link_names if n not in joints or n not in lens]
    if missing:
        raise TruthError(f"{path}: the pose does not fit skeleton {skel.name!r}: no value for link(s) "
                         f"{', '.join(missing[:5])}")
    angles = np.zeros((L, 3))
    lengths = np.zeros(L)
    for i, (n, jt) in enumerate(zip(skel.link_names, skel.joint_types)):
        angles[i, : JOINT_DOF[jt]] = num(joints[n], f"joints.{n}", (JOINT_DOF[jt],))
        lengths[i] = num(lens[n], f"lengths.{n}", ())
    f32 = lambda a: jnp.asarray(a, jnp.float32)  # noqa: E731
    return Pose(f32(num(p["root_translation"], "root_translation", (3,))), f32(num(p["root_rpy"], "root_rpy", (3,))),
                f32(num(p["scale"], "scale", ())), f32(angles), f32(lengths))


def resolve_relative(path_in_file: str | None, relative_to: str) -> str | None:
    """A path stored in a JSON file, resolved against that file's folder."""
    if path_in_file is None:
        return None
    if os.path.isabs(path_in_file):
        return path_in_file
    return os.path.join(os.path.dirname(os.path.abspath(relative_to)), path_in_file)
