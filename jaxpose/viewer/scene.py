"""What ``jaxpose view`` shows, as plain NumPy data: no browser, no viser.

:func:`load_view` reads a ``result.json`` (and a truth file), a tracked sequence's
folder (``track.json`` and one result per frame) or a folder of results into a
:class:`View`; the functions below turn its links and points into what the viewer
draws: capsule meshes, point colours, joint frames, the camera frustum and the
viewpoint of a screenshot.  Every coordinate is in the result's frame (the camera's
or the sensor's: x right, y down, z forward, metres).  docs/viewer.md.
"""

from __future__ import annotations

import json
import math
import os
import re
from dataclasses import dataclass, field

import numpy as np

from ..camera import KINECT_V1, Intrinsics
from ..io.truth import TruthError, _load_json

MODES = ("global", "tracked", "lost")  # a tracked frame's mode (jaxpose track)
DISTANCE_RANGE = 0.05  # metres: "distance to the model" colours run from 0 to this and saturate beyond
DEFAULT_FPS = 10.0  # playback of a sequence whose track.json records no rate


@dataclass(frozen=True)
class Link:
    """One capsule: the link's name and parent, its joint anchor, capsule ends and radius (metres)."""

    name: str
    parent: str | None
    origin: np.ndarray
    start: np.ndarray
    end: np.ndarray
    radius: float


@dataclass
class Frame:
    """One fit: its links, the points it used (``None`` when unknown, with ``note`` saying
    why), its cost and, in a tracked sequence, its frame number and mode."""

    source: str
    links: list[Link]
    points: np.ndarray | None
    note: str | None = None
    cost: float | None = None
    frame: int | None = None
    mode: str | None = None
    wall_seconds: float | None = None
    intrinsics: Intrinsics | None = None  # depth images: the camera; clouds: None


@dataclass
class View:
    """Everything the viewer shows: one frame (a single fit) or several (a sequence)."""

    frames: list[Frame]
    truth: list[Link] | None = None
    fps: float | None = None  # a sequence's playback rate (track.json's summary)
    title: str = ""
    notes: list[str] = field(default_factory=list)  # one line each, printed by the command

    @property
    def is_sequence(self) -> bool:
        return len(self.frames) > 1 or self.fps is not None


# --------------------------------------------------------------------------- reading


def _links(path: str, doc: dict) -> list[Link]:
    items = doc.get("links")
    if not isinstance(items, list) or not items:
        raise TruthError(f"{path}: needs a non-empty 'links' list of {{name, parent, start, end}}")
    out = []
    for n, item in enumerate(items):
        if not isinstance(item, dict) or not isinstance(item.get("name"), str):
            raise TruthError(f"{path}: link #{n + 1} needs a string 'name'")
        try:
            start = np.asarray(item["start"], np.float64).reshape(3)
            end = np.asarray(item["end"], np.float64).reshape(3)
            origin = np.asarray(item.get("origin", item["start"]), np.float64).reshape(3)
            radius = float(item.get("radius", 0.0))
        except (KeyError, TypeError, ValueError):
            raise TruthError(f"{path}: link {item['name']!r}: 'start', 'end' (and 'origin') must be 3 numbers "
                             "each, 'radius' a number") from None
        if not all(np.all(np.isfinite(a)) for a in (start, end, origin)) or not (math.isfinite(radius)
                                                                                  and radius >= 0):
            raise TruthError(f"{path}: link {item['name']!r}: end points must be finite and the radius >= 0")
        parent = item.get("parent")
        out.append(Link(item["name"], parent if isinstance(parent, str) else None, origin, start, end, radius))
    return out


def _stored_points(path: str, doc: dict) -> np.ndarray | None:
    pts = doc.get("points")
    if pts is None:
        return None
    try:
        a = np.asarray(pts, np.float64).reshape(-1, 3)
    except (TypeError, ValueError):
        raise TruthError(f"{path}: 'points' must be a list of [x, y, z] in metres") from None
    if not np.all(np.isfinite(a)):
        raise TruthError(f"{path}: 'points' must be finite")
    return a


def _intrinsics(doc: dict) -> Intrinsics | None:
    k = (doc.get("input") or {}).get("intrinsics") if isinstance(doc.get("input"), dict) else None
    try:
        return Intrinsics(float(k["fx"]), float(k["fy"]), float(k["cx"]), float(k["cy"]),
                          int(k["width"]), int(k["height"]))
    except (TypeError, KeyError, ValueError):
        return None


def _find(name: str, sha256: str | None, result_path: str, hint: str | None = None) -> tuple[str | None, str | None]:
    """An input recorded by ``name`` and hash: beside the result, else in the working folder,
    else at ``hint`` (a sequence's ``track.json`` entry: as given, or from the result's folder).
    Returns ``(path, None)`` or ``(None, why not)``."""
    from ..io.fit_result import file_sha256

    here = os.path.dirname(os.path.abspath(result_path))
    places = [os.path.join(here, name), os.path.abspath(name)]
    if hint and os.path.basename(hint) == name:
        places += [os.path.abspath(hint), os.path.join(here, hint)]
    changed = None
    for p in dict.fromkeys(places):
        if os.path.isfile(p):
            if sha256 is None or file_sha256(p) == sha256:
                return p, None
            changed = p
    if changed:
        return None, f"{changed} is not the file that was fitted (its sha256 differs)"
    return None, f"{name} is neither beside the result nor in the working folder"


def rebuild_points(path: str, doc: dict, hint: str | None = None) -> tuple[np.ndarray | None, str | None]:
    """The points of a result that does not store them (written before ``points`` was
    recorded, or by another tool), rebuilt from its input file with the recorded options:
    ``(points, None)``, or ``(None, why not)`` when the input is not found, differs from
    the fitted one (its sha256), or cannot be read."""
    from ..errors import JaxposeError
    from ..pipeline import InputOptions, load_cloud_observation, load_observation

    inp = doc.get("input")
    if not isinstance(inp, dict):
        return None, "the result records no input"
    common = {k: inp[k] for k in ("near", "far", "max_points", "sample_seed", "remove_planes", "plane_tolerance")
              if k in inp}
    try:
        if isinstance(inp.get("cloud"), str):
            src, why = _find(inp["cloud"], inp.get("cloud_sha256"), path, hint)
            if src is None:
                return None, why
            options = InputOptions(cloud_scale=float(inp.get("cloud_scale", 1.0)),
                                   viewpoint=tuple(inp["viewpoint"]) if inp.get("viewpoint") else None, **common)
            cloud = load_cloud_observation(src, options)[2]
        elif isinstance(inp.get("depth"), str):
            src, why = _find(inp["depth"], inp.get("depth_sha256"), path, hint)
            if src is None:
                return None, why
            background = None
            if isinstance(inp.get("background"), str):
                background, why = _find(inp["background"], inp.get("background_sha256"), path,
                                        hint and os.path.join(os.path.dirname(hint), inp["background"]))
                if background is None:
                    return None, f"background {why}"
            k = _intrinsics(doc) or KINECT_V1
            options = InputOptions(intrinsics=f"{k.fx},{k.fy},{k.cx},{k.cy}", background=background,
                                   depth_scale=float(inp.get("depth_scale") or 0.001), **common)
            cloud = load_observation(src, options)[2]
        else:
            return None, "the result records no input file"
    except (JaxposeError, OSError, TypeError, ValueError) as e:
        return None, f"its input cannot be read again ({' '.join(str(e).split())})"
    pts = np.asarray(cloud.points, np.float64)[np.asarray(cloud.weights) > 0]
    return pts, None


def read_frame(path: str, doc: dict | None = None, hint: str | None = None) -> Frame:
    """One result file as a :class:`Frame` (its points stored, else rebuilt from its input;
    ``hint``: where else the input may be, :func:`rebuild_points`)."""
    doc = _load_json(path) if doc is None else doc
    links = _links(path, doc)
    points, note = _stored_points(path, doc), None
    if points is None:
        points, why = rebuild_points(path, doc, hint)
        if points is None:
            note = f"{path}: no points shown: the result does not store them and {why}; showing the model alone"
    cost = doc.get("cost")
    tracking = doc.get("tracking")
    mode = tracking.get("mode") if isinstance(tracking, dict) else tracking
    return Frame(path, links, points, note, float(cost) if isinstance(cost, (int, float)) else None,
                 mode=mode if isinstance(mode, str) else None, intrinsics=_intrinsics(doc))


def _natural(name: str):
    return [int(t) if t.isdigit() else t.casefold() for t in re.split(r"(\d+)", name)]


def _number(value, what: str, path: str, integer: bool = False):
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise TruthError(f"{path}: {what} must be a number, got {value!r:.40}")
    return int(value) if integer else float(value)


def read_sequence(folder: str) -> View:
    """A tracked sequence's folder: ``track.json`` lists the frames in order (``input``,
    ``frame``, ``mode``, ``cost``, ``wall_seconds``; ``summary.fps``), each frame's result is
    ``<input name>.json`` beside it."""
    track = os.path.join(folder, "track.json")
    doc = _load_json(track)
    entries = doc.get("frames")
    if not isinstance(entries, list) or not entries:
        raise TruthError(f"{track}: needs a non-empty 'frames' list of {{input, frame, mode, cost}}")
    frames = []
    for i, e in enumerate(entries):
        if not isinstance(e, dict) or not isinstance(e.get("input"), str):
            raise TruthError(f"{track}: frame #{i + 1} needs a string 'input'")
        stem = os.path.splitext(os.path.basename(e["input"]))[0]
        path = os.path.join(folder, stem + ".json")
        if not os.path.isfile(path):
            raise TruthError(f"{track}: the result of frame #{i + 1} ({e['input']}), {path}, is missing")
        f = read_frame(path, hint=e["input"])
        f.frame = _number(e.get("frame", i), "'frame'", track, integer=True)
        mode = e.get("mode", f.mode)
        if mode is not None and mode not in MODES:
            raise TruthError(f"{track}: frame #{i + 1}: mode {mode!r} is not one of {', '.join(MODES)}")
        f.mode = mode
        cost = _number(e.get("cost"), "'cost'", track)
        f.cost = f.cost if cost is None else cost
        f.wall_seconds = _number(e.get("wall_seconds"), "'wall_seconds'", track)
        frames.append(f)
    summary = doc.get("summary") if isinstance(doc.get("summary"), dict) else {}
    fps = _number(summary.get("fps"), "summary.fps", track)
    fps = fps if fps is not None and fps > 0 else DEFAULT_FPS
    return View(frames, fps=fps, title=os.path.basename(os.path.normpath(folder)),
                notes=_notes(frames))


def read_folder(folder: str) -> View:
    """A folder of results (``jaxpose fit --out-dir``): every ``*.json`` with a ``links``
    list, in natural name order (``f2`` before ``f10``)."""
    frames = []
    for name in sorted(os.listdir(folder), key=_natural):
        path = os.path.join(folder, name)
        if not name.lower().endswith(".json") or not os.path.isfile(path):
            continue
        try:
            with open(path) as fh:
                doc = json.load(fh)
        except (OSError, ValueError):
            continue  # not a result: skipped
        if isinstance(doc, dict) and isinstance(doc.get("links"), list) and doc["links"]:
            frames.append(read_frame(path, doc))
            frames[-1].frame = len(frames) - 1
    if not frames:
        raise TruthError(f"{folder}: holds no result file (a .json with a 'links' list)")
    return View(frames, fps=DEFAULT_FPS if len(frames) > 1 else None,
                title=os.path.basename(os.path.normpath(folder)), notes=_notes(frames))


def _notes(frames: list[Frame]) -> list[str]:
    missing = [f for f in frames if f.note]
    if not missing:
        return []
    if len(frames) == 1 or len(missing) == 1:
        return [missing[0].note]
    return [f"{len(missing)} of {len(frames)} frames show no points (the first: {missing[0].note})"]


def load_view(path: str, truth: str | None = None) -> View:
    """A result file (with an optional truth file, whose links are drawn too), a tracked
    sequence's folder (``track.json``) or a folder of results.  Raises
    :class:`~jaxpose.io.truth.TruthError` for a missing or malformed file."""
    path = str(path)
    if os.path.isdir(path):
        if truth is not None:
            raise TruthError(f"{truth}: a truth file goes with one result file, not with the folder {path}")
        if os.path.isfile(os.path.join(path, "track.json")):
            return read_sequence(path)
        return read_folder(path)
    frame = read_frame(path)
    view = View([frame], title=os.path.basename(path), notes=_notes([frame]))
    if truth is not None:
        view.truth = _links(str(truth), _load_json(str(truth)))
    return view


# --------------------------------------------------------------------------- geometry


def _basis(axis: np.ndarray) -> np.ndarray:
    """A right-handed orthonormal basis (columns) whose first column is ``axis``."""
    n = float(np.linalg.norm(axis))
    x = axis / n if n > 1e-12 else np.array([0.0, 0.0, 1.0])
    helper = np.array([0.0, 1.0, 0.0]) if abs(x[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    y = np.cross(helper, x)
    y /= np.linalg.norm(y)
    return np.stack([x, y, np.cross(x, y)], axis=1)


def capsule_mesh(start, end, radius: float, segments: int = 16, rings: int = 6) -> tuple[np.ndarray, np.ndarray]:
    """A closed triangle mesh of the capsule (the points within ``radius`` of the segment
    ``start``-``end``): ``(vertices (V, 3) float32, faces (F, 3) uint32)``, outward-facing.
    A link of length zero is a sphere."""
    start, end = np.asarray(start, np.float64), np.asarray(end, np.float64)
    frame = _basis(end - start)
    ax, u, v = frame[:, 0], frame[:, 1], frame[:, 2]
    r = max(float(radius), 1e-4)
    phis = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    ring_dirs = np.cos(phis)[:, None] * u + np.sin(phis)[:, None] * v  # (S, 3)
    # latitude from -pi/2 (the start's pole) to +pi/2 (the end's): rings per hemisphere
    lats = np.concatenate([np.linspace(-np.pi / 2, 0, rings + 1)[1:], np.linspace(0, np.pi / 2, rings + 1)[:-1]])
    verts = [start - r * ax]
    for j, lat in enumerate(lats):
        centre = start if j < rings else end
        verts.extend(centre + r * (np.cos(lat) * ring_dirs + np.sin(lat) * ax))
    verts.append(end + r * ax)
    n_rings, s = len(lats), segments
    faces = []
    ring = lambda j, k: 1 + j * s + (k % s)  # noqa: E731
    for k in range(s):  # the start's cap: the pole, then ring 0
        faces.append((0, ring(0, k + 1), ring(0, k)))
    for j in range(n_rings - 1):
        for k in range(s):
            a, b, c, d = ring(j, k), ring(j, k + 1), ring(j + 1, k), ring(j + 1, k + 1)
            faces.extend([(a, b, d), (a, d, c)])
    top = len(verts) - 1
    for k in range(s):
        faces.append((top, ring(n_rings - 1, k), ring(n_rings - 1, k + 1)))
    return np.asarray(verts, np.float32), np.asarray(faces, np.uint32)


def distances_to_links(points: np.ndarray, links: list[Link]) -> np.ndarray:
    """Each point's distance to the nearest capsule surface (0 inside a capsule), metres."""
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    best = np.full(len(pts), np.inf)
    for link in links:
        d = link.end - link.start
        t = np.clip((pts - link.start) @ d / max(float(d @ d), 1e-18), 0.0, 1.0)
        dist = np.linalg.norm(pts - (link.start + t[:, None] * d), axis=1) - link.radius
        best = np.minimum(best, np.maximum(dist, 0.0))
    return best


# viridis at 0, 1/4, 1/2, 3/4, 1
_VIRIDIS = np.array([[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98], [253, 231, 37]], np.float64)


def colormap(values: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Viridis colours (``(N, 3)`` uint8) of values scaled from ``lo`` (dark blue) to ``hi`` (yellow)."""
    t = np.clip((np.asarray(values, np.float64) - lo) / max(hi - lo, 1e-12), 0.0, 1.0) * (len(_VIRIDIS) - 1)
    i = np.minimum(t.astype(int), len(_VIRIDIS) - 2)
    f = (t - i)[:, None]
    return np.round(_VIRIDIS[i] * (1 - f) + _VIRIDIS[i + 1] * f).astype(np.uint8)


def point_colours(points: np.ndarray, mode: str = "depth", links: list[Link] | None = None) -> np.ndarray:
    """``(N, 3)`` uint8 colours: ``"depth"`` (z, nearest dark blue to farthest yellow) or
    ``"distance"`` (to the nearest capsule: 0 dark blue, :data:`DISTANCE_RANGE` or more yellow)."""
    pts = np.asarray(points, np.float64).reshape(-1, 3)
    if len(pts) == 0:
        return np.zeros((0, 3), np.uint8)
    if mode == "depth":
        return colormap(pts[:, 2], float(pts[:, 2].min()), float(pts[:, 2].max()))
    if mode == "distance":
        return colormap(distances_to_links(pts, links or []), 0.0, DISTANCE_RANGE)
    raise ValueError(f"unknown colour mode {mode!r} (depth or distance)")


def link_colours(n: int) -> np.ndarray:
    """``(n, 3)`` uint8: one distinct colour per link (tab10, repeated)."""
    tab10 = np.array([[31, 119, 180], [255, 127, 14], [44, 160, 44], [214, 39, 40], [148, 103, 189],
                      [140, 86, 75], [227, 119, 194], [127, 127, 127], [188, 189, 34], [23, 190, 207]], np.uint8)
    return tab10[np.arange(n) % len(tab10)]


def wxyz_from_matrix(r: np.ndarray) -> np.ndarray:
    """The unit quaternion (w, x, y, z) of a rotation matrix."""
    r = np.asarray(r, np.float64)
    w = math.sqrt(max(0.0, 1 + r[0, 0] + r[1, 1] + r[2, 2])) / 2
    x = math.copysign(math.sqrt(max(0.0, 1 + r[0, 0] - r[1, 1] - r[2, 2])) / 2, r[2, 1] - r[1, 2])
    y = math.copysign(math.sqrt(max(0.0, 1 - r[0, 0] + r[1, 1] - r[2, 2])) / 2, r[0, 2] - r[2, 0])
    z = math.copysign(math.sqrt(max(0.0, 1 - r[0, 0] - r[1, 1] + r[2, 2])) / 2, r[1, 0] - r[0, 1])
    q = np.array([w, x, y, z])
    return q / np.linalg.norm(q)


def joint_frames(links: list[Link]) -> list[tuple[np.ndarray, np.ndarray]]:
    """``(position, wxyz)`` of a frame at each link's joint anchor, its x axis along the
    link (start to end); the result does not store the joints' own axes."""
    return [(link.origin, wxyz_from_matrix(_basis(link.end - link.start))) for link in links]


def frustum(k: Intrinsics | None) -> tuple[float, float]:
    """``(vertical field of view in radians, aspect)`` of the camera at the origin (the
    Kinect v1's for a point cloud, whose sensor records none)."""
    k = k or KINECT_V1
    return 2 * math.atan2(k.height / 2, k.fy), k.width / k.height


def look_at(position, target) -> np.ndarray:
    """The wxyz of a camera at ``position`` looking at ``target`` (x right, y down, z
    forward; the picture's down is the frame's +y, as in the sensor's image)."""
    f = np.asarray(target, np.float64) - np.asarray(position, np.float64)
    f /= np.linalg.norm(f)
    x = np.cross([0.0, 1.0, 0.0], f)
    if np.linalg.norm(x) < 1e-9:  # looking straight up or down
        x = np.array([1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    return wxyz_from_matrix(np.stack([x, np.cross(f, x), f], axis=1))


def bounds(frame: Frame, truth: list[Link] | None = None) -> tuple[np.ndarray, float]:
    """``(centre, radius)`` of what a frame shows: its links (ends and radii), points and truth."""
    links = frame.links + (truth or [])
    pts = [np.array([link.start for link in links]), np.array([link.end for link in links])]
    if frame.points is not None and len(frame.points):
        pts.append(frame.points)
    allp = np.concatenate(pts)
    lo, hi = allp.min(0), allp.max(0)
    centre = (lo + hi) / 2
    pad = max(link.radius for link in links)
    return centre, float(np.linalg.norm(hi - lo) / 2 + pad)


def orbit_camera(frame: Frame, truth: list[Link] | None = None, azimuth: float = 35.0, elevation: float = 25.0,
                 fov: float = 0.8) -> tuple[np.ndarray, np.ndarray]:
    """``(position, wxyz)`` of a camera looking at the middle of the scene from ``azimuth``
    degrees round the frame's vertical and ``elevation`` degrees above the sensor's line
    of sight (0, 0: from the sensor's side), far enough back for the scene to fill about
    two thirds of a ``fov`` (vertical, radians) picture."""
    centre, radius = bounds(frame, truth)
    dist = radius / math.tan(fov / 2) * 1.1
    az, el = math.radians(azimuth), math.radians(elevation)
    offset = np.array([math.sin(az) * math.cos(el), -math.sin(el), -math.cos(az) * math.cos(el)])
    position = centre + dist * offset
    return position, look_at(position, centre)


def node_names(view: View, index: int = 0) -> list[str]:
    """The scene nodes the viewer draws for frame ``index``: the points (when known), one
    capsule per link, one per truth link, a joint frame per link and the camera frustum."""
    f = view.frames[index]
    names = (["/points"] if f.points is not None else []) + [f"/fit/{link.name}" for link in f.links]
    names += [f"/truth/{link.name}" for link in view.truth or []]
    names += [f"/joints/{link.name}" for link in f.links]
    return names + ["/camera"]


def frame_caption(view: View, index: int) -> str:
    """The panel's line about frame ``index``: its number, mode and cost."""
    f = view.frames[index]
    parts = [f"frame {f.frame if f.frame is not None else index}" if view.is_sequence else os.path.basename(f.source)]
    if f.mode:
        parts.append(f.mode)
    if f.cost is not None:
        parts.append(f"cost {f.cost:.4f}")
    if f.wall_seconds is not None:
        parts.append(f"{f.wall_seconds:.2f} s")
    return ", ".join(parts)
