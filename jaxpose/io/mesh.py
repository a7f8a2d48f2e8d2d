"""Mesh files named by robot descriptions: finding them and reading their vertices.

A URDF names a mesh by a path relative to its own folder, a ``file://`` path, or
``package://PKG/...``, looked up as ``PKG/...`` and as ``...`` in the URDF's folder and
the three folders above it (ROS packages are not resolved).  Wavefront ``.obj`` and STL
(binary or ASCII) files are read; only their vertices matter, since a capsule encloses
them or is fitted to them (:mod:`jaxpose.io.capsules`).
"""

from __future__ import annotations

import os

import numpy as np

MESH_FORMATS = (".obj", ".stl")


def find_mesh_file(filename: str, base: str) -> str | None:
    """The mesh file a URDF ``filename`` names, looked up beside the URDF file in folder
    ``base`` (see the module docstring), or ``None`` when not found or not a readable format."""
    if os.path.splitext(filename)[1].lower() not in MESH_FORMATS:
        return None
    candidates = []
    if filename.startswith("package://"):
        rest = filename[len("package://"):]
        tail = rest.split("/", 1)[1] if "/" in rest else rest
        folder = os.path.abspath(base)
        for _ in range(4):  # the URDF's folder and three above it
            candidates += [os.path.join(folder, rest), os.path.join(folder, tail)]
            folder = os.path.dirname(folder)
    else:
        name = filename[len("file://"):] if filename.startswith("file://") else filename
        candidates.append(name if os.path.isabs(name) else os.path.join(base, name))
    return next((c for c in candidates if os.path.isfile(c)), None)


def read_mesh_vertices(path: str) -> np.ndarray:
    """Vertices ``(n, 3)`` of a Wavefront ``.obj`` or an STL file (binary or ASCII).

    Raises ``ValueError`` for a file that holds no vertex or is malformed.
    """
    try:
        with open(path, "rb") as f:
            raw = f.read(64 << 20)
    except OSError as e:
        raise ValueError(f"cannot read the mesh ({e.strerror or e})") from None
    ext = os.path.splitext(path)[1].lower()
    rows = []
    binary_size = len(raw) >= 84 and len(raw) == 84 + 50 * int.from_bytes(raw[80:84], "little")
    if ext == ".stl" and (binary_size or not raw[:5].lower().startswith(b"solid")):  # ASCII starts with "solid"
        if len(raw) < 84:
            raise ValueError("not an STL file (shorter than its 84-byte header)")
        n = int.from_bytes(raw[80:84], "little")
        if len(raw) < 84 + 50 * n:
            raise ValueError(f"binary STL announces {n} triangles but holds {(len(raw) - 84) // 50}")
        tri = np.frombuffer(raw, np.dtype([("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")]), n, 84)
        v = tri["v"].reshape(-1, 3).astype(float)
    else:
        key = b"v" if ext == ".obj" else b"vertex"
        for line in raw.splitlines():
            parts = line.split()
            if len(parts) >= 4 and parts[0] == key:
                try:
                    rows.append([float(x) for x in parts[1:4]])
                except ValueError:
                    raise ValueError(f"malformed vertex line {line[:60].decode('utf-8', 'replace')!r}") from None
        v = np.asarray(rows, float).reshape(-1, 3)
    if v.shape[0] == 0:
        raise ValueError("the mesh holds no vertex")
    if not np.all(np.isfinite(v)):
        raise ValueError("the mesh has non-finite vertex coordinates")
    v = np.unique(v, axis=0)
    if v.shape[0] > 4096:  # only the convex hull matters for an enclosing capsule
        try:
            from scipy.spatial import ConvexHull

            v = v[ConvexHull(v).vertices]
        except Exception:  # noqa: BLE001 - flat or degenerate mesh: keep every vertex
            pass
    return v
