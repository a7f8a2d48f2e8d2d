"""Depth images and intrinsics from files.

- ``.png``: 16-bit single-channel depth in millimetres (the Kinect convention);
  ``depth_scale`` (default 0.001) converts the stored integers to metres.
- ``.npy``: a 2-D float array of depth in metres (NaN/inf/0: no measurement).
- Intrinsics: ``kinect`` (the v1 preset), ``fx,fy,cx,cy``, or a JSON file with
  keys ``fx, fy, cx, cy`` (and optionally ``width, height``).
"""

from __future__ import annotations

import json
import os

import numpy as np

from ..camera import KINECT_V1, Intrinsics, check_intrinsics
from ..errors import DepthError, IntrinsicsError

MAX_PIXELS = 10_000 * 10_000


def load_depth(path: str, depth_scale: float = 0.001) -> np.ndarray:
    """Read a depth image as float32 metres (NaN where there is no measurement).

    Raises :class:`DepthError` for a missing or unreadable file, an RGB or 8-bit
    image, a wrong shape, or an absurd size.
    """
    path = str(path)
    if not os.path.exists(path):
        raise DepthError(f"{path}: depth file not found")
    if os.path.isdir(path):
        raise DepthError(f"{path}: is a directory, not a depth image")
    if not (np.isfinite(depth_scale) and depth_scale > 0):
        raise DepthError(f"{path}: depth scale must be a positive number, got {depth_scale}")
    ext = os.path.splitext(path)[1].lower()
    if ext == ".npy":
        try:
            arr = np.load(path, allow_pickle=False)
        except (OSError, ValueError, EOFError) as e:
            raise DepthError(f"{path}: not a readable .npy array ({e})") from None
        if arr.dtype.kind not in "fiu":
            raise DepthError(f"{path}: .npy depth must be numeric, got dtype {arr.dtype}")
        arr = arr.astype(np.float32)
        if arr.dtype.kind == "f" and arr.ndim == 3 and arr.shape[-1] == 1:
            arr = arr[..., 0]
        _check_shape(arr, path)
        depth = arr
    else:
        try:
            import imageio.v3 as iio

            img = iio.imread(path)
        except Exception as e:  # imageio raises many types for unreadable files
            raise DepthError(f"{path}: not a readable image ({e.__class__.__name__})") from None
        img = np.asarray(img)
        if img.ndim == 3:
            raise DepthError(
                f"{path}: image has {img.shape[2]} channels; expected a single-channel 16-bit depth image"
            )
        if img.dtype == np.uint8 or img.dtype == bool:
            raise DepthError(f"{path}: image is 8-bit; expected 16-bit depth in millimetres")
        if img.dtype.kind not in "uif":
            raise DepthError(f"{path}: unsupported pixel type {img.dtype}")
        _check_shape(img, path)
        depth = img.astype(np.float32) * np.float32(depth_scale)
        if img.dtype.kind in "ui":
            depth[img == 0] = np.nan
    depth = depth.astype(np.float32)
    depth[~np.isfinite(depth) | (depth <= 0)] = np.nan
    return depth


def _check_shape(arr, path):
    if arr.ndim != 2:
        raise DepthError(f"{path}: expected a 2-D depth image, got shape {arr.shape}")
    h, w = arr.shape
    if h < 2 or w < 2 or h * w > MAX_PIXELS:
        raise DepthError(f"{path}: absurd image size {w}x{h}")


def parse_intrinsics(spec: str | None, shape=None) -> Intrinsics:
    """``kinect`` | ``fx,fy,cx,cy`` | path to a JSON file -> validated :class:`Intrinsics`."""
    h, w = shape if shape is not None else (KINECT_V1.height, KINECT_V1.width)
    if spec is None or spec == "kinect":
        k = KINECT_V1._replace(width=w, height=h)
        return check_intrinsics(k, shape, "intrinsics 'kinect'")
    if os.path.splitext(spec)[1].lower() == ".json" or os.path.exists(spec):
        if not os.path.exists(spec):
            raise IntrinsicsError(f"{spec}: intrinsics file not found")
        try:
            with open(spec) as f:
                data = json.load(f)
        except (OSError, json.JSONDecodeError, UnicodeDecodeError) as e:
            raise IntrinsicsError(f"{spec}: not valid intrinsics JSON ({e})") from None
        if not isinstance(data, dict) or not all(key in data for key in ("fx", "fy", "cx", "cy")):
            raise IntrinsicsError(f"{spec}: intrinsics JSON needs numeric keys fx, fy, cx, cy")
        try:
            k = Intrinsics(float(data["fx"]), float(data["fy"]), float(data["cx"]), float(data["cy"]),
                           int(data.get("width", w)), int(data.get("height", h)))
        except (TypeError, ValueError):
            raise IntrinsicsError(f"{spec}: fx, fy, cx, cy must be numbers") from None
        return check_intrinsics(k, shape, spec)
    parts = spec.split(",")
    if len(parts) != 4:
        raise IntrinsicsError(f"intrinsics {spec!r}: expected 'kinect', 'fx,fy,cx,cy' or a JSON file")
    try:
        fx, fy, cx, cy = (float(p) for p in parts)
    except ValueError:
        raise IntrinsicsError(f"intrinsics {spec!r}: fx,fy,cx,cy must be numbers") from None
    return check_intrinsics(Intrinsics(fx, fy, cx, cy, w, h), shape, f"intrinsics {spec!r}")


def save_depth_png(path: str, depth_m: np.ndarray, depth_scale: float = 0.001) -> None:
    """Write metres as a 16-bit PNG (0 = no measurement), atomically."""
    import imageio.v3 as iio

    from .results import atomic_write

    d = np.asarray(depth_m, np.float64) / depth_scale
    d = np.where(np.isfinite(d) & (d > 0), np.round(d), 0)
    img = np.clip(d, 0, 65535).astype(np.uint16)
    atomic_write(path, lambda f: iio.imwrite(f, img, extension=".png"), binary=True)
