"""Depth images and intrinsics from files.

- ``.png``: 16-bit single-channel depth in millimetres (the Kinect convention);
  ``depth_scale`` (default 0.001) converts the stored integers to metres.
- Other single-channel images imageio reads (e.g. ``.tif``, ``.pfm``): integer
  pixels are stored units like a PNG's (times ``depth_scale``); float pixels are
  metres (the convention of float depth maps: ROS ``32FC1``, renderers' Z passes).
- ``.npy``: a 2-D float array of depth in metres (NaN/inf/0: no measurement);
  an integer array holds stored units like a PNG (times ``depth_scale``).
- Intrinsics: ``kinect`` (the v1 preset, 640x480 images), ``fx,fy,cx,cy``, or a
  JSON file with keys ``fx, fy, cx, cy`` (and optionally ``width, height``), or a
  truth file of ``jaxpose render`` / a result file of ``jaxpose fit``.

Every problem raises :class:`~jaxpose.errors.DepthError` or
:class:`~jaxpose.errors.IntrinsicsError` naming the file and the problem
(see docs/errors.md).
"""

from __future__ import annotations

import json
import os

import numpy as np

from ..camera import KINECT_V1, Intrinsics, check_intrinsics
from ..errors import DepthError, IntrinsicsError

MAX_PIXELS = 10_000 * 10_000
MAX_JSON_BYTES = 16 * 1024 * 1024


def load_depth(path: str, depth_scale: float = 0.001) -> np.ndarray:
    """Read a depth image as float32 metres (NaN where there is no measurement).

    Raises :class:`DepthError` for a missing or unreadable file, an RGB or 8-bit
    image, a wrong shape, or an absurd size (checked from the file's header,
    before the pixels are decoded).
    """
    return read_depth(path, depth_scale)[0]


def read_depth(path: str, depth_scale: float = 0.001) -> tuple[np.ndarray, bool]:
    """:func:`load_depth`, and whether ``depth_scale`` was applied: ``False`` for float
    pixels, which are metres already."""
    path = check_input_file(path, "depth file", "a depth image")
    try:
        depth_scale = float(depth_scale)
    except (TypeError, ValueError):
        raise DepthError(f"{path}: depth scale must be a positive number, got {depth_scale!r}") from None
    if not (np.isfinite(depth_scale) and depth_scale > 0):
        raise DepthError(f"{path}: depth scale must be a positive number, got {depth_scale}")
    ext = os.path.splitext(path)[1].lower()
    if ext == ".npy":
        depth, scaled = _read_npy(path, depth_scale)
    else:
        depth, scaled = _read_image(path, depth_scale)
    depth = depth.astype(np.float32)
    with np.errstate(invalid="ignore"):
        depth[~np.isfinite(depth) | (depth <= 0)] = np.nan
    return depth, scaled


def check_input_file(path, noun: str, thing: str) -> str:
    """``path`` as a string, or :class:`DepthError` when it is missing, a directory,
    not a regular file (a FIFO would block) or empty; ``noun``/``thing`` name the
    kind of input ("depth file" / "a depth image")."""
    path = str(path)
    if not os.path.exists(path):
        raise DepthError(f"{path}: {noun} not found")
    if os.path.isdir(path):
        raise DepthError(f"{path}: is a directory, not {thing}")
    if not os.path.isfile(path):
        raise DepthError(f"{path}: not a regular file")
    if os.path.getsize(path) == 0:
        raise DepthError(f"{path}: the {noun} is empty")
    return path


def _read_npy(path: str, depth_scale: float) -> tuple[np.ndarray, bool]:
    """A 2-D numeric ``.npy`` array, its header checked before the data is read.

    Floats are metres; integers are stored units (like a PNG's), times ``depth_scale``.
    """
    try:
        shape, dtype = npy_header(path)
        if dtype is not None:
            _check_npy(path, shape, dtype)
        arr = np.load(path, mmap_mode="r", allow_pickle=False)
    except DepthError:
        raise
    except Exception as e:  # a corrupt header raises ValueError, SyntaxError, tokenize.TokenError, ...
        raise DepthError(f"{path}: not a readable .npy array ({_short(e)})") from None
    if not isinstance(arr, np.ndarray):  # e.g. an .npz archive renamed to .npy
        raise DepthError(f"{path}: not a single .npy array")
    _check_npy(path, arr.shape, arr.dtype)
    integer = arr.dtype.kind in "iu"
    arr = np.array(arr, np.float32)
    if integer:
        arr *= np.float32(depth_scale)
    if arr.ndim == 3 and arr.shape[-1] == 1:
        arr = arr[..., 0]
    return arr, integer


def npy_header(path: str):
    """``(shape, dtype)`` from a ``.npy`` file's header, without reading the data
    (``(None, None)`` for a header version this reader does not know).  Raises
    :class:`DepthError` when the file has no NumPy header; a corrupt header raises
    ``ValueError`` or ``SyntaxError``."""
    with open(path, "rb") as f:
        if f.read(6) != b"\x93NUMPY":
            raise DepthError(f"{path}: not a .npy file (no NumPy array header)")
        f.seek(0)
        version = np.lib.format.read_magic(f)
        if version == (1, 0):
            shape, _, dtype = np.lib.format.read_array_header_1_0(f)
        elif version == (2, 0):
            shape, _, dtype = np.lib.format.read_array_header_2_0(f)
        else:
            return None, None
    return shape, dtype


def _check_npy(path, shape, dtype):
    if dtype.kind not in "fiu":
        raise DepthError(f"{path}: .npy depth must be a numeric array (metres), got dtype {dtype}")
    if len(shape) == 3 and shape[-1] == 1:
        shape = shape[:2]
    if len(shape) == 2 and shape[1] == 3 and dtype.kind in "iu":
        raise DepthError(f"{path}: an integer array of shape {tuple(int(s) for s in shape)}: a point cloud needs "
                         "float coordinates (metres, or another unit with --cloud-scale)")
    if len(shape) != 2:
        raise DepthError(f"{path}: expected a 2-D depth image or a float point array of shape (N, 3) or "
                         f"(H, W, 3), got {dtype} of shape {tuple(int(s) for s in shape)}")
    _check_shape(shape, path)


def _png_header(path: str):
    """``(width, height, bit_depth, colour_type)`` from a PNG's IHDR chunk, or None if not a PNG."""
    with open(path, "rb") as f:
        head = f.read(29)
    if len(head) < 29 or head[:8] != b"\x89PNG\r\n\x1a\n" or head[12:16] != b"IHDR":
        return None
    w, h = int.from_bytes(head[16:20], "big"), int.from_bytes(head[20:24], "big")
    return w, h, head[24], head[25]


_PNG_CHANNELS = {0: 1, 2: 3, 3: 3, 4: 2, 6: 4}


def _read_image(path: str, depth_scale: float) -> tuple[np.ndarray, bool]:
    """A single-channel 16-bit (or other integer) image scaled to metres, or a float image in metres."""
    try:
        hdr = _png_header(path)
    except OSError as e:
        raise DepthError(f"{path}: cannot read the file ({_short(e)})") from None
    if hdr is not None:
        w, h, bits, colour = hdr
        _check_shape((h, w), path)
        channels = _PNG_CHANNELS.get(colour)
        if channels is not None and channels > 1:
            kind = "is a palette (colour) image" if colour == 3 else f"has {channels} channels"
            raise DepthError(f"{path}: image {kind}; expected a single-channel 16-bit depth image")
        if channels == 1 and bits < 16:
            raise DepthError(f"{path}: image is {bits}-bit; expected 16-bit depth in millimetres")
    elif os.path.splitext(path)[1].lower() == ".png":
        raise DepthError(f"{path}: not a PNG image (expected a 16-bit PNG in millimetres or a .npy array in metres)")
    try:
        import imageio.v3 as iio

        img = iio.imread(path)
    except Exception as e:  # imageio raises many types for unreadable files
        raise DepthError(
            f"{path}: not a readable depth image ({e.__class__.__name__}; "
            "expected a 16-bit PNG in millimetres or a .npy array in metres)"
        ) from None
    img = np.asarray(img)
    if img.ndim == 3:
        raise DepthError(
            f"{path}: image has {img.shape[2]} channels; expected a single-channel 16-bit depth image"
        )
    if img.dtype == np.uint8 or img.dtype == bool:
        raise DepthError(f"{path}: image is 8-bit; expected 16-bit depth in millimetres")
    if img.dtype.kind not in "uif":
        raise DepthError(f"{path}: unsupported pixel type {img.dtype}")
    _check_shape(img.shape, path)
    if img.dtype.kind == "f":  # float depth maps are metres, like a float .npy
        return img.astype(np.float32), False
    depth = img.astype(np.float32) * np.float32(depth_scale)
    depth[img == 0] = np.nan
    return depth, True


def _short(e: BaseException, n: int = 120) -> str:
    msg = " ".join(str(e).split()) or e.__class__.__name__
    return msg if len(msg) <= n else msg[: n - 3] + "..."


def _check_shape(shape, path):
    shape = tuple(int(s) for s in shape)
    if len(shape) != 2:
        raise DepthError(f"{path}: expected a 2-D depth image, got shape {shape}")
    h, w = shape
    if h < 2 or w < 2 or h * w > MAX_PIXELS:
        raise DepthError(f"{path}: absurd image size {w}x{h} (expected 2x2 to {MAX_PIXELS:,} pixels)")


def parse_intrinsics(spec: str | None, shape=None, image: str | None = None) -> Intrinsics:
    """``kinect`` | ``fx,fy,cx,cy`` | path to a JSON file -> validated :class:`Intrinsics`.

    A JSON file holds ``fx, fy, cx, cy`` (and optionally ``width, height``) at its
    top level, or is a truth file of ``jaxpose render`` (``camera.intrinsics``) or
    a result file of ``jaxpose fit`` (``input.intrinsics``).  With the ``shape``
    of a depth image (named ``image`` in messages), the ``kinect`` preset needs a
    640x480 image and a JSON file's ``width, height`` must match it.
    """
    h, w = shape if shape is not None else (KINECT_V1.height, KINECT_V1.width)
    of = f" {image}" if image else ""
    if spec is None or spec == "kinect":
        if (h, w) != (KINECT_V1.height, KINECT_V1.width):
            raise IntrinsicsError(
                f"intrinsics 'kinect' are for {KINECT_V1.width}x{KINECT_V1.height} images, but the depth image{of} "
                f"is {w}x{h}: pass --intrinsics fx,fy,cx,cy or a JSON file (e.g. the truth file of jaxpose render)"
            )
        return check_intrinsics(KINECT_V1, shape, "intrinsics 'kinect'")
    if not isinstance(spec, str):
        raise IntrinsicsError(f"intrinsics {spec!r}: expected 'kinect', 'fx,fy,cx,cy' or a JSON file")
    if os.path.splitext(spec)[1].lower() == ".json" or os.path.exists(spec):
        return _intrinsics_json(spec, shape, (h, w), of)
    parts = spec.split(",")
    if len(parts) != 4:
        raise IntrinsicsError(
            f"intrinsics {spec!r}: expected 'kinect', 4 numbers 'fx,fy,cx,cy' (got {len(parts)}) or a JSON file"
        )
    try:
        fx, fy, cx, cy = (float(p) for p in parts)
    except ValueError:
        raise IntrinsicsError(f"intrinsics {spec!r}: fx,fy,cx,cy must be numbers") from None
    return check_intrinsics(Intrinsics(fx, fy, cx, cy, w, h), shape, f"intrinsics {spec!r}")


def _intrinsics_json(spec: str, shape, hw, of: str) -> Intrinsics:
    h, w = hw
    if not os.path.exists(spec):
        raise IntrinsicsError(f"{spec}: intrinsics file not found")
    if not os.path.isfile(spec):
        raise IntrinsicsError(f"{spec}: not a regular file (expected an intrinsics JSON file)")
    try:
        with open(spec, "rb") as f:
            raw = f.read(MAX_JSON_BYTES + 1)
        if len(raw) > MAX_JSON_BYTES:
            raise IntrinsicsError(f"{spec}: more than {MAX_JSON_BYTES} bytes; not an intrinsics JSON file")
        data = json.loads(raw.decode("utf-8"))
    except IntrinsicsError:
        raise
    except (OSError, ValueError, RecursionError) as e:  # JSONDecodeError and UnicodeDecodeError are ValueErrors
        raise IntrinsicsError(f"{spec}: not valid intrinsics JSON ({_short(e)})") from None
    if isinstance(data, dict) and "fx" not in data:  # a truth file (camera.intrinsics) or a result (input.intrinsics)
        for outer in ("camera", "input"):
            sub = data.get(outer)
            if isinstance(sub, dict) and isinstance(sub.get("intrinsics"), dict):
                data = sub["intrinsics"]
                break
    if not isinstance(data, dict) or not all(key in data for key in ("fx", "fy", "cx", "cy")):
        raise IntrinsicsError(f"{spec}: intrinsics JSON needs numeric keys fx, fy, cx, cy")
    try:
        vals = [data[key] for key in ("fx", "fy", "cx", "cy")] + [data.get("width", w), data.get("height", h)]
        if any(isinstance(v, (bool, str)) or v is None for v in vals):
            raise TypeError
        fx, fy, cx, cy = (float(v) for v in vals[:4])
        width, height = vals[4:]
        if float(width) != int(width) or float(height) != int(height):
            raise ValueError
        k = Intrinsics(fx, fy, cx, cy, int(width), int(height))
    except (TypeError, ValueError, OverflowError):
        raise IntrinsicsError(f"{spec}: fx, fy, cx, cy (and width, height) must be numbers") from None
    if shape is not None and (k.height, k.width) != (h, w):
        raise IntrinsicsError(
            f"{spec}: intrinsics are for {k.width}x{k.height} images, but the depth image{of} is {w}x{h}"
        )
    return check_intrinsics(k, shape, spec)


def save_depth_png(path: str, depth_m: np.ndarray, depth_scale: float = 0.001) -> None:
    """Write metres as a 16-bit PNG (0 = no measurement), atomically."""
    import imageio.v3 as iio

    from .atomic import atomic_write

    d = np.asarray(depth_m, np.float64) / depth_scale
    d = np.where(np.isfinite(d) & (d > 0), np.round(d), 0)
    img = np.clip(d, 0, 65535).astype(np.uint16)
    atomic_write(path, lambda f: iio.imwrite(f, img, extension=".png"), binary=True)
