"""Point-cloud files: ``.ply``, ``.pcd``, ``.xyz`` and ``(N, 3)`` / ``(H, W, 3)`` ``.npy`` arrays.

- ``.ply``: the ``vertex`` element's ``x, y, z`` properties, in ``ascii``,
  ``binary_little_endian`` or ``binary_big_endian`` (other elements, such as
  faces, may come before or after the vertices and are skipped).
- ``.pcd`` (the Point Cloud Library's format, versions 0.6 and 0.7): the ``x, y, z``
  fields in ``DATA ascii``, ``binary`` or ``binary_compressed`` (LZF), organised
  (``HEIGHT > 1``) or not; its ``VIEWPOINT`` is the sensor's pose in the cloud's
  frame.
- ``.xyz``: text, one point per line, the first three whitespace-separated
  numbers are ``x y z`` (further columns, such as colours, are ignored; ``#``
  starts a comment).
- ``.npy``: a float array of shape ``(N, 3)`` or ``(H, W, 3)`` (an organised
  cloud).  A 2-D array of another shape is a depth image (``depth_file``).

Coordinates are read as float32 in the file's unit; NaN/inf points (the holes
of an organised cloud) are kept here and dropped by the pipeline.  Every problem
raises :class:`~jaxpose.errors.DepthError` naming the file and the problem; the
header's counts are checked against the file's size before anything is allocated.

Why one module of about 500 lines: the readers are one idea, a point-cloud file
to float32 points, and share its guards (the bounded header, the counts checked
against the file's size, the text rows, the ``x, y, z`` columns) section by
section (PLY, PCD with its LZF decoder, XYZ and NumPy); split by format, each
reader would import those private helpers back from here.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass

import numpy as np

from ..errors import DepthError
from ..geometry import quat_to_matrix
from .depth_file import _short, check_input_file, npy_header

CLOUD_EXTENSIONS = (".ply", ".pcd", ".xyz")
MAX_CLOUD_POINTS = 100_000_000
MAX_HEADER_BYTES = 64 * 1024
IDENTITY_VIEWPOINT = (0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)


@dataclass(frozen=True)
class PointFile:
    """The points of a cloud file: ``points (M, 3)`` float32 (NaN rows: no
    measurement), the ``format`` read, and the file's ``viewpoint`` (``tx, ty, tz,
    qw, qx, qy, qz``: the sensor's pose in the cloud's frame; identity unless a PCD
    header says otherwise)."""

    points: np.ndarray
    format: str
    viewpoint: tuple = IDENTITY_VIEWPOINT


def is_cloud_file(path: str) -> bool:
    """Whether ``path`` names a point-cloud file (by extension; a ``.npy`` by its
    header: a float array whose last axis has 3 entries, of 2 or 3 dimensions)."""
    ext = os.path.splitext(str(path))[1].lower()
    if ext in CLOUD_EXTENSIONS:
        return True
    if ext == ".npy" and os.path.isfile(path):
        try:
            shape, dtype = npy_header(path)
        except Exception:  # no NumPy header, or a corrupt one: load_depth says what is wrong
            return False
        return shape is not None and _npy_cloud_shape(shape) and dtype.kind == "f"
    return False


def _npy_cloud_shape(shape) -> bool:
    return len(shape) in (2, 3) and shape[-1] == 3 and (len(shape) == 3 or shape[0] != 0)


def load_points(path: str) -> PointFile:
    """Read a point-cloud file (see the module docstring); raise :class:`DepthError`."""
    path = check_input_file(path, "point-cloud file", "a point cloud")
    ext = os.path.splitext(path)[1].lower()
    readers = {".ply": _read_ply, ".pcd": _read_pcd, ".xyz": _read_xyz, ".npy": _read_npy_points}
    try:
        if ext in readers:
            with np.errstate(over="ignore", invalid="ignore"):  # doubles beyond float32 read as inf (dropped later)
                return readers[ext](path)
    except DepthError:
        raise
    except OSError as e:
        raise DepthError(f"{path}: cannot read the file ({_short(e)})") from None
    except (ValueError, IndexError, KeyError, OverflowError, TypeError, MemoryError) as e:
        # a backstop: every case the readers know of has its own message above
        raise DepthError(f"{path}: not a readable {ext} point cloud ({_short(e)})") from None
    raise DepthError(f"{path}: not a point-cloud file (expected .ply, .pcd, .xyz or an (N, 3) .npy array)")


def _check_count(path: str, n: int, what: str) -> int:
    if n < 0 or n > MAX_CLOUD_POINTS:
        raise DepthError(f"{path}: absurd point count {n} in the {what} (expected 0 to {MAX_CLOUD_POINTS:,})")
    return n


def _xyz_columns(path: str, names: list[str], what: str) -> list[int]:
    missing = [c for c in "xyz" if c not in names]
    if missing:
        have = ", ".join(names) if names else "none"
        raise DepthError(f"{path}: the {what} has no {', '.join(missing)} (it has {have})")
    return [names.index(c) for c in "xyz"]


def _header(path: str, first: bytes, end: re.Pattern, what: str) -> tuple[list[str], int]:
    """The header's lines (decoded) and the byte offset just after it."""
    with open(path, "rb") as f:
        head = f.read(MAX_HEADER_BYTES)
    if not head.startswith(first):
        raise DepthError(f"{path}: not a {what} file (it does not start with {first.decode().strip()!r})")
    m = end.search(head)
    if m is None:
        raise DepthError(f"{path}: the {what} header does not end within {MAX_HEADER_BYTES // 1024} KiB")
    text = head[: m.start()].decode("ascii", errors="replace")
    return [ln.strip() for ln in text.splitlines()], m.end()


def _read_body(path: str, offset: int) -> bytes:
    with open(path, "rb") as f:
        f.seek(offset)
        return f.read()


def _text_rows(path: str, body: bytes, count: int, columns: list[int], what: str, row: str) -> np.ndarray:
    """``count`` text rows of ``body`` (``what``: their plural, ``row``: one of them, for
    messages); the given columns as float32 ``(count, len(columns))``."""
    lines = body.split(b"\n", count)[:count] if count else []
    if len(lines) < count or (count and not lines[-1].strip()):
        got = sum(1 for ln in lines if ln.strip())
        raise DepthError(f"{path}: the file ends after {got} of {count} {what}")
    out = np.empty((count, len(columns)), np.float32)
    for i, ln in enumerate(lines):
        tok = ln.split()
        try:
            out[i] = [float(tok[c]) for c in columns]
        except (IndexError, ValueError):
            text = _short(ln.decode("ascii", "replace"), 60)
            raise DepthError(f"{path}: {row} {i + 1} is not a row of numbers ({text!r})") from None
    return out


# ---------------------------------------------------------------------------------------- PLY

_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
    "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
_PLY_END = re.compile(rb"(?:^|\n)end_header[ \t]*\r?\n")


@dataclass
class _PlyElement:
    name: str
    count: int
    props: list  # (name, type) or (name, (count type, item type)) for a list


def _read_ply(path: str) -> PointFile:
    lines, offset = _header(path, b"ply", _PLY_END, "PLY")
    fmt, elements = None, []
    for ln in lines[1:]:
        tok = ln.split()
        if not tok or tok[0] in ("comment", "obj_info"):
            continue
        if tok[0] == "format" and len(tok) >= 2:
            fmt = tok[1]
        elif tok[0] == "element" and len(tok) == 3:
            try:
                count = int(tok[2])
            except ValueError:
                raise DepthError(f"{path}: PLY element {tok[1]!r} has a count that is not a number: "
                                 f"{tok[2]!r}") from None
            elements.append(_PlyElement(tok[1], _check_count(path, count, f"PLY element {tok[1]!r}"), []))
        elif tok[0] == "property" and elements:
            if len(tok) == 5 and tok[1] == "list":
                types = (tok[2], tok[3])
                name = tok[4]
            elif len(tok) == 3:
                types, name = tok[1], tok[2]
            else:
                raise DepthError(f"{path}: malformed PLY header line {ln!r}")
            for t in types if isinstance(types, tuple) else (types,):
                if t not in _PLY_TYPES:
                    raise DepthError(f"{path}: unknown PLY property type {t!r} in {ln!r}")
            if isinstance(types, tuple) and _PLY_TYPES[types[0]][0] != "u" and _PLY_TYPES[types[0]][0] != "i":
                raise DepthError(f"{path}: a PLY list's count must have an integer type, not {types[0]!r} in {ln!r}")
            elements[-1].props.append((name, types))
        else:
            raise DepthError(f"{path}: malformed PLY header line {ln!r}")
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise DepthError(f"{path}: unknown PLY format {fmt!r} (expected ascii, binary_little_endian or "
                         "binary_big_endian)")
    names = [e.name for e in elements]
    if "vertex" not in names:
        raise DepthError(f"{path}: the PLY file has no vertex element (it has {', '.join(names) or 'none'})")
    body = _read_body(path, offset)
    if fmt == "ascii":
        return PointFile(_ply_ascii(path, body, elements), "ply ascii")
    return PointFile(_ply_binary(path, body, elements, "<" if fmt == "binary_little_endian" else ">"), f"ply {fmt}")


def _ply_ascii(path: str, body: bytes, elements: list) -> np.ndarray:
    for e in elements:
        if e.name == "vertex":
            vertex = e
            break
        body = body.split(b"\n", e.count)[-1] if e.count else body  # skip the rows of an earlier element
    if any(isinstance(t, tuple) for _, t in vertex.props):
        raise DepthError(f"{path}: PLY vertices with list properties are not supported")
    cols = _xyz_columns(path, [n for n, _ in vertex.props], "PLY vertex element")
    return _text_rows(path, body, vertex.count, cols, "vertices", "vertex")


def _ply_binary(path: str, body: bytes, elements: list, endian: str) -> np.ndarray:
    pos = 0
    for e in elements:
        if any(isinstance(t, tuple) for _, t in e.props):
            if e.name == "vertex":
                raise DepthError(f"{path}: PLY vertices with list properties are not supported")
            pos = _skip_list_element(path, body, pos, e, endian)
            continue
        dtype = np.dtype([(f"p{i}", endian + _PLY_TYPES[t]) for i, (_, t) in enumerate(e.props)])
        if e.name != "vertex":
            pos += e.count * dtype.itemsize
            continue
        cols = _xyz_columns(path, [n for n, _ in e.props], "PLY vertex element")
        need = e.count * dtype.itemsize
        if pos + need > len(body):
            got = max(0, (len(body) - pos) // max(dtype.itemsize, 1))
            raise DepthError(f"{path}: the file ends after {got} of {e.count} vertices")
        rows = np.frombuffer(body, dtype, e.count, pos)
        return np.stack([rows[f"p{c}"].astype(np.float32) for c in cols], -1).reshape(-1, 3)
    raise AssertionError("unreachable: the vertex element exists")


def _skip_list_element(path: str, body: bytes, pos: int, e: _PlyElement, endian: str) -> int:
    """Skip the rows of a binary element with list properties (faces before the vertices)."""
    for _ in range(e.count):
        for _, t in e.props:
            if isinstance(t, tuple):
                ct, it = (np.dtype(endian + _PLY_TYPES[x]) for x in t)
                if pos + ct.itemsize > len(body):
                    raise DepthError(f"{path}: the file ends inside the PLY element {e.name!r}")
                n = int(np.frombuffer(body, ct, 1, pos)[0])
                if n < 0:
                    raise DepthError(f"{path}: a list of the PLY element {e.name!r} has a negative length {n}")
                pos += ct.itemsize + n * it.itemsize
            else:
                pos += np.dtype(_PLY_TYPES[t]).itemsize
        if pos > len(body):
            raise DepthError(f"{path}: the file ends inside the PLY element {e.name!r}")
    return pos


# ---------------------------------------------------------------------------------------- PCD

_PCD_TYPES = {("F", 4): "f4", ("F", 8): "f8", ("I", 1): "i1", ("I", 2): "i2", ("I", 4): "i4", ("I", 8): "i8",
              ("U", 1): "u1", ("U", 2): "u2", ("U", 4): "u4", ("U", 8): "u8"}


def _pcd_header(path: str) -> tuple[dict, int]:
    """The header's keywords (first token of each non-comment line, upper case) and
    their values, up to and including the DATA line; and the offset of the data."""
    with open(path, "rb") as f:
        head = f.read(MAX_HEADER_BYTES)
    header, pos = {}, 0
    whole = len(head) < MAX_HEADER_BYTES  # the file ends within what was read
    for line in head.split(b"\n"):
        end = pos + len(line) + 1
        if end > len(head) and not whole:
            break
        tok = line.decode("ascii", errors="replace").split()
        pos = end
        if not tok or tok[0].startswith("#"):
            continue
        key = tok[0].upper()
        if not header and key not in ("VERSION", "FIELDS"):
            raise DepthError(f"{path}: not a PCD file (it does not start with a VERSION or FIELDS line)")
        header[key] = tok[1:]
        if key == "DATA":
            return header, min(pos, len(head))
    if not header:
        raise DepthError(f"{path}: not a PCD file (it does not start with a VERSION or FIELDS line)")
    raise DepthError(f"{path}: the PCD header has no DATA line within {MAX_HEADER_BYTES // 1024} KiB")


def _read_pcd(path: str) -> PointFile:
    header, offset = _pcd_header(path)

    def ints(key, default=None, lo=0, hi=MAX_CLOUD_POINTS):
        vals = header.get(key, default)
        if not vals:
            raise DepthError(f"{path}: the PCD header's {key} line has no value")
        try:
            out = [int(v) for v in vals]
        except ValueError:
            raise DepthError(f"{path}: the PCD header's {key} must be integers, got {' '.join(vals)}") from None
        if any(not lo <= v <= hi for v in out):
            raise DepthError(f"{path}: the PCD header's {key} must lie within {lo} .. {hi}, got {' '.join(vals)}")
        return out

    fields = header.get("FIELDS", [])
    n_fields = len(fields)
    sizes = ints("SIZE", [], 1, 8)
    types = [t.upper() for t in header.get("TYPE", [])]
    counts = ints("COUNT", ["1"] * n_fields, 1, 1_000_000)
    width, height = ints("WIDTH", ["0"])[0], ints("HEIGHT", ["1"])[0]
    points = ints("POINTS", [str(width * height)])[0]
    try:
        viewpoint = parse_viewpoint(header.get("VIEWPOINT", list(IDENTITY_VIEWPOINT)))
    except ValueError as e:
        raise DepthError(f"{path}: the PCD VIEWPOINT (tx ty tz qw qx qy qz): {e}") from None
    if not (len(sizes) == len(types) == len(counts) == n_fields) or n_fields == 0:
        raise DepthError(f"{path}: the PCD header's FIELDS, SIZE, TYPE and COUNT do not have one entry per field")
    if points != width * height:
        raise DepthError(f"{path}: the PCD header says POINTS {points} but WIDTH x HEIGHT = {width} x {height}")
    _check_count(path, points, "PCD header")
    kinds = []
    for name, t, sz in zip(fields, types, sizes):
        if (t, sz) not in _PCD_TYPES:
            raise DepthError(f"{path}: PCD field {name!r} has an unknown TYPE {t} / SIZE {sz}")
        kinds.append(_PCD_TYPES[(t, sz)])
    cols = _xyz_columns(path, fields, "PCD file")
    if any(counts[c] != 1 for c in cols):
        raise DepthError(f"{path}: the PCD fields x, y, z must have COUNT 1")
    data = header["DATA"][0].lower() if header["DATA"] else ""
    body = _read_body(path, offset)
    row = sum(np.dtype(k).itemsize * c for k, c in zip(kinds, counts))
    if data == "ascii":
        offsets = np.cumsum([0] + counts[:-1])
        body = b"\n".join(ln for ln in body.splitlines() if ln.strip())  # blank lines are skipped, as PCL does
        pts = _text_rows(path, body, points, [int(offsets[c]) for c in cols], "points", "point")
    elif data == "binary":
        if points * row > len(body):
            raise DepthError(f"{path}: the file ends after {len(body) // row} of {points} points")
        dtype = np.dtype([(f"f{i}", "<" + k, (c,)) if c > 1 else (f"f{i}", "<" + k)
                          for i, (k, c) in enumerate(zip(kinds, counts))])
        rows = np.frombuffer(body, dtype, points)
        pts = np.stack([rows[f"f{c}"].astype(np.float32) for c in cols], -1).reshape(-1, 3)
    elif data == "binary_compressed":
        pts = _pcd_compressed(path, body, points, fields, kinds, counts, cols)
    else:
        raise DepthError(f"{path}: unknown PCD DATA {data!r} (expected ascii, binary or binary_compressed)")
    return PointFile(pts, f"pcd {data}", viewpoint)


def _pcd_compressed(path, body, points, fields, kinds, counts, cols) -> np.ndarray:
    """``binary_compressed``: sizes (2 x uint32), then LZF of the fields one after another.
    PCL leaves padding fields (named ``_``) out of this layout; a file that keeps them
    is read too (the uncompressed size tells which)."""
    if len(body) < 8:
        raise DepthError(f"{path}: the compressed PCD data is truncated")
    csize, usize = (int(v) for v in np.frombuffer(body, "<u4", 2))
    widths = [np.dtype(k).itemsize * c for k, c in zip(kinds, counts)]
    packed = [0 if f == "_" else w for f, w in zip(fields, widths)]
    if usize == points * sum(widths):
        packed = widths
    elif usize != points * sum(packed):
        raise DepthError(f"{path}: the compressed PCD data holds {usize} bytes, {points * sum(packed)} expected "
                         f"for {points} points")
    if 8 + csize > len(body):
        raise DepthError(f"{path}: the compressed PCD data is truncated ({len(body) - 8} of {csize} bytes)")
    if usize > 88 * csize + 32:  # LZF expands at most 88-fold (3 bytes of a reference -> 264)
        raise DepthError(f"{path}: the compressed PCD data is corrupt ({csize} bytes cannot hold {usize})")
    try:
        raw = lzf_decompress(body[8: 8 + csize], usize)
    except ValueError as e:
        raise DepthError(f"{path}: the compressed PCD data is corrupt ({e})") from None
    starts = np.cumsum([0] + [points * w for w in packed])
    out = [np.frombuffer(raw, "<" + kinds[c], points, int(starts[c])).astype(np.float32) for c in cols]
    return np.stack(out, -1).reshape(-1, 3)


def lzf_decompress(data: bytes, size: int) -> bytearray:
    """LZF (liblzf's format, as used by PCD's ``binary_compressed``) -> exactly ``size`` bytes.

    Each control byte ``c`` starts either a literal run (``c < 32``: the next
    ``c + 1`` bytes) or a back reference (length ``c >> 5`` plus 2, with an extra
    length byte when that field is 7; offset ``(c & 31) << 8`` plus the next byte,
    plus 1, back from the end of the output).  Raises ``ValueError`` when the
    stream is corrupt or does not give ``size`` bytes."""
    out = bytearray(size)
    i = o = 0
    n = len(data)
    while i < n:
        c = data[i]
        i += 1
        if c < 32:
            k = c + 1
            if i + k > n or o + k > size:
                raise ValueError("a literal run overruns the stream")
            out[o: o + k] = data[i: i + k]
            i += k
            o += k
            continue
        k = c >> 5
        if k == 7:
            if i >= n:
                raise ValueError("the stream ends inside a back reference")
            k += data[i]
            i += 1
        k += 2
        if i >= n:
            raise ValueError("the stream ends inside a back reference")
        ref = o - ((c & 31) << 8) - data[i] - 1
        i += 1
        if ref < 0 or o + k > size:
            raise ValueError("a back reference points outside the output")
        period = o - ref
        if period >= k:
            out[o: o + k] = out[ref: ref + k]
        else:  # overlapping: the last `period` bytes repeat
            out[o: o + k] = (bytes(out[ref:o]) * (k // period + 1))[:k]
        o += k
    if o != size:
        raise ValueError(f"it gives {o} bytes, {size} expected")
    return out


# ---------------------------------------------------------------------------------------- XYZ, NPY


def _read_xyz(path: str) -> PointFile:
    body = _read_body(path, 0)
    if b"\0" in body[:4096]:
        raise DepthError(f"{path}: not a text .xyz file (binary data)")
    rows = [ln for ln in (ln.split(b"#", 1)[0] for ln in body.splitlines()) if ln.strip()]
    _check_count(path, len(rows), ".xyz file")
    return PointFile(_text_rows(path, b"\n".join(rows), len(rows), [0, 1, 2], "points", "point"), "xyz")


def _read_npy_points(path: str) -> PointFile:
    try:
        shape, dtype = npy_header(path)
    except DepthError:
        raise
    except Exception as e:  # a corrupt header raises ValueError, SyntaxError, tokenize.TokenError, ...
        raise DepthError(f"{path}: not a readable .npy array ({_short(e)})") from None
    if shape is None or not _npy_cloud_shape(shape) or dtype.kind != "f":
        raise DepthError(f"{path}: expected a float .npy array of shape (N, 3) or (H, W, 3), "
                         f"got {dtype if dtype is not None else 'no'} array of shape {shape}")
    _check_count(path, int(np.prod(shape[:-1])), ".npy header")
    try:
        arr = np.load(path, mmap_mode="r", allow_pickle=False)
    except Exception as e:  # a truncated file raises ValueError, OSError, ...
        raise DepthError(f"{path}: not a readable .npy array ({_short(e)})") from None
    return PointFile(np.array(arr, np.float32).reshape(-1, 3), "npy")


def parse_viewpoint(spec) -> tuple:
    """``tx,ty,tz,qw,qx,qy,qz`` (a string or 7 numbers) -> a validated 7-tuple; the
    quaternion is normalised.  Raises ``ValueError`` with the reason."""
    parts = spec.split(",") if isinstance(spec, str) else list(spec)
    if len(parts) != 7:
        raise ValueError(f"expected 7 numbers tx,ty,tz,qw,qx,qy,qz, got {len(parts)}")
    try:
        v = [float(p) for p in parts]
    except (TypeError, ValueError):
        raise ValueError("tx,ty,tz,qw,qx,qy,qz must be numbers") from None
    if not np.all(np.isfinite(v)):
        raise ValueError(f"values must be finite, got {v}")
    q = np.array(v[3:])
    if np.linalg.norm(q) < 1e-9:
        raise ValueError("the quaternion qw,qx,qy,qz is zero")
    return tuple(v[:3]) + tuple(float(x) for x in q / np.linalg.norm(q))


def to_sensor_frame(points: np.ndarray, viewpoint) -> np.ndarray:
    """Points of the cloud's frame -> the sensor's frame (``R^T (p - t)``, with the
    sensor's pose ``t, q = (qw, qx, qy, qz)`` in the cloud's frame)."""
    if tuple(viewpoint) == IDENTITY_VIEWPOINT:
        return np.asarray(points, np.float32)
    t = np.asarray(viewpoint[:3], np.float64)
    r = quat_to_matrix(np.asarray(viewpoint[3:], np.float64), xp=np)
    return ((np.asarray(points, np.float64) - t) @ r).astype(np.float32)


def save_points_ply(path: str, points: np.ndarray) -> None:
    """Write ``(M, 3)`` points as a binary little-endian PLY (float x, y, z), atomically."""
    from .atomic import atomic_write

    pts = np.ascontiguousarray(points, "<f4").reshape(-1, 3)
    head = (f"ply\nformat binary_little_endian 1.0\ncomment jaxpose: sensor frame (x right, y down, z forward), "
            f"metres\nelement vertex {len(pts)}\nproperty float x\nproperty float y\nproperty float z\n"
            "end_header\n").encode()
    atomic_write(path, lambda f: (f.write(head), f.write(pts.tobytes())), binary=True)
