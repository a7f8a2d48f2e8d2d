"""Pinhole intrinsics, depth images to point clouds, and projection.

Camera frame: x right, y down, z forward (the OpenCV convention); depth is z.
Depth values of 0, NaN or inf mean "no measurement" and are dropped.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .errors import DepthError, IntrinsicsError
from .objective import Cloud


class Intrinsics(NamedTuple):
    fx: float
    fy: float
    cx: float
    cy: float
    width: int = 640
    height: int = 480


KINECT_V1 = Intrinsics(525.0, 525.0, 319.5, 239.5, 640, 480)


def check_intrinsics(k: Intrinsics, shape=None, source: str = "intrinsics") -> Intrinsics:
    """Validate intrinsics (optionally against an image ``shape``); raise :class:`IntrinsicsError`."""
    try:
        vals = [float(v) for v in (k.fx, k.fy, k.cx, k.cy)]
    except (TypeError, ValueError):
        raise IntrinsicsError(f"{source}: fx, fy, cx, cy must be numbers, got {list(k[:4])}") from None
    if not all(np.isfinite(v) for v in vals):
        raise IntrinsicsError(f"{source}: values must be finite numbers, got {list(k[:4])}")
    if k.fx <= 0 or k.fy <= 0:
        raise IntrinsicsError(f"{source}: focal lengths must be positive, got fx={k.fx}, fy={k.fy}")
    if shape is None:
        try:
            ok = int(k.width) == k.width and int(k.height) == k.height and k.width >= 1 and k.height >= 1
        except (TypeError, ValueError, OverflowError):
            ok = False
        if not ok:
            raise IntrinsicsError(f"{source}: width and height must be positive integers, got {k.width}x{k.height}")
    h, w = (k.height, k.width) if shape is None else shape[:2]
    if not (0 <= k.cx <= w and 0 <= k.cy <= h):
        raise IntrinsicsError(
            f"{source}: principal point ({k.cx}, {k.cy}) lies outside the {w}x{h} image"
        )
    return k


def depth_to_points(depth: np.ndarray, k: Intrinsics) -> tuple[np.ndarray, np.ndarray]:
    """All pixels to camera-frame points: ``(H*W, 3)`` and a validity mask ``(H*W,)``."""
    h, w = depth.shape
    v, u = np.mgrid[0:h, 0:w]
    z = depth.astype(np.float64)
    valid = np.isfinite(z) & (z > 0)
    z = np.where(valid, z, 0.0)
    x = (u - k.cx) * z / k.fx
    y = (v - k.cy) * z / k.fy
    return np.stack([x, y, z], -1).reshape(-1, 3), valid.reshape(-1)


def foreground_mask(
    depth: np.ndarray,
    near: float = 0.3,
    far: float = 8.0,
    background: np.ndarray | None = None,
    background_tolerance: float = 0.05,
    background_noise: float = 0.0045,
    min_neighbours: int = 2,
) -> np.ndarray:
    """Pixels that carry a measurement within ``[near, far]`` metres and, when a
    background depth image ``b`` is given, lie more than
    ``background_tolerance + background_noise * b**2`` metres in front of it (the
    second part follows the depth sensor's noise, which grows with the square of
    depth: 0.0045 is three standard deviations of a Kinect v1).  Pixels where the
    background has no measurement are kept.  Isolated speckles (foreground pixels
    with fewer than ``min_neighbours`` foreground pixels among their 8 neighbours)
    are dropped."""
    z = depth.astype(np.float64)
    with np.errstate(invalid="ignore"):
        mask = np.isfinite(z) & (z > 0) & (z >= near) & (z <= far)
        if background is not None:
            b = background.astype(np.float64)
            bvalid = np.isfinite(b) & (b > 0)
            tol = background_tolerance + background_noise * np.where(bvalid, b, 0.0) ** 2
            mask &= ~bvalid | (z < b - tol)
    if min_neighbours > 0:
        m = np.pad(mask, 1).astype(np.int32)
        h, w = mask.shape
        n = sum(m[1 + dy:1 + dy + h, 1 + dx:1 + dx + w] for dy in (-1, 0, 1) for dx in (-1, 0, 1)) - mask
        mask &= n >= min_neighbours
    return mask


def depth_to_cloud(
    depth: np.ndarray,
    intrinsics: Intrinsics = KINECT_V1,
    near: float = 0.3, far: float = 8.0,
    background: np.ndarray | None = None,
    max_points: int = 1024, seed: int = 0, min_points: int = 50,
    background_tolerance: float = 0.05,
    source: str = "depth image",
    remove_planes: int = 0, plane_tolerance: float = 0.02,
) -> Cloud:
    """Depth image (metres) -> fixed-size :class:`Cloud` of ``max_points`` points.

    Background removal keeps pixels within ``[near, far]`` and, with a background
    image, those in front of it.  When more than ``max_points`` pixels remain, a
    deterministic random subset (NumPy generator seeded with ``seed``) is kept;
    when fewer, the cloud is padded with weight-0 points.  ``remove_planes``: drop
    the points of that many largest planes first (:func:`off_planes`, within
    ``plane_tolerance`` plus the depth noise), for an image without a background
    image.  Raises :class:`DepthError` when fewer than ``min_points`` points remain.
    """
    depth = np.asarray(depth)
    if depth.dtype.kind not in "fiu":
        raise DepthError(f"{source}: depth must be a numeric array (metres), got dtype {depth.dtype}")
    if depth.ndim != 2:
        raise DepthError(f"{source}: expected a single-channel depth image, got shape {depth.shape}")
    if background is not None:
        background = np.asarray(background)
        if background.dtype.kind not in "fiu":
            raise DepthError(f"{source}: background must be a numeric array (metres), got dtype {background.dtype}")
        if background.shape != depth.shape:
            size = lambda a: f"{a.shape[1]}x{a.shape[0]}" if a.ndim == 2 else f"of shape {a.shape}"  # noqa: E731
            raise DepthError(f"{source}: background image is {size(background)}, the depth image is {size(depth)}")
    check_intrinsics(intrinsics, depth.shape)
    _check_sampling(near, far, max_points, source)
    pts, valid = depth_to_points(depth, intrinsics)
    n_valid = int(valid.sum())
    if n_valid == 0:
        raise DepthError(f"{source}: the image holds no depth measurement (every pixel is 0, NaN or inf)")
    zv = depth.reshape(-1)[valid]
    if not np.any((zv >= near) & (zv <= far)):
        raise DepthError(
            f"{source}: no depth measurement lies within near={near} m .. far={far} m "
            f"(the measured depths span {float(zv.min()):.4g} .. {float(zv.max()):.4g} m; "
            "check the near/far range and the depth scale)"
        )
    mask = foreground_mask(depth, near, far, background, background_tolerance).reshape(-1)
    subtracted = ", background subtracted" if background is not None else ""
    idx = _off_planes_enough(pts, np.flatnonzero(mask), min_points, remove_planes, plane_tolerance, seed, source,
                             f"left after background removal (near={near} m, far={far} m{subtracted}"
                             f"{_planes_note(remove_planes)})")
    return _subsample(pts, idx, max_points, seed)



def off_planes(
    points: np.ndarray,
    count: int = 1,
    tolerance: float = 0.02, noise: float = 0.0045,
    min_fraction: float = 0.2, max_spread: float = 0.35, min_cover: float = 0.5,
    seed: int = 0,
) -> np.ndarray:
    """Which points lie off the ``count`` largest planes (a floor, a wall): a mask.

    Each plane is found by RANSAC: planes through 3 random points, as many as
    find a plane holding ``min_fraction`` of the points with 99% probability
    (574 for a fifth), scored on at most 2048 of the points; the best is refitted
    by least squares to its inliers.  A point is on a plane within ``tol =
    tolerance + noise * z**2`` metres (the depth noise grows with the square of
    depth, like the background tolerance of :func:`foreground_mask`).  A plane is
    removed only when it holds at least ``min_fraction`` of the points left, is
    flat (the RMS of its points' distances in units of ``tol`` at most
    ``max_spread``) and is a surface rather than a few thin parts that happen to
    line up (its points cover at least ``min_cover`` of a 16 x 16 grid over their
    extent in the plane); the thresholds and what floors and bodies measure:
    docs/input.md, "Planes".  The search stops at the first plane that fails.  Float32
    coordinates (so that a depth image and its points written as a cloud give
    the same mask); deterministic for a ``seed``."""
    p = np.asarray(points, np.float32).astype(np.float64)
    keep = np.ones(len(p), bool)
    rng = np.random.default_rng([seed, 1])  # a stream of its own: the subsample draws from `seed`
    tol = np.maximum(tolerance + noise * p[:, 2] ** 2, 1e-6)
    tries = int(np.ceil(np.log(0.01) / np.log1p(-(min_fraction ** 3)))) if 0 < min_fraction < 1 else 64
    for _ in range(count):
        idx = np.flatnonzero(keep)
        if len(idx) < 3:
            break
        sample = idx if len(idx) <= 2048 else np.sort(rng.choice(idx, 2048, replace=False))
        best, best_n = None, -1
        for start in range(0, tries, 256):
            tri = p[rng.choice(sample, (min(256, tries - start), 3))]  # (hypotheses, 3 points, 3)
            n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
            norm = np.linalg.norm(n, axis=1)
            ok = norm > 1e-12
            if not ok.any():
                continue
            n, a = n[ok] / norm[ok, None], tri[ok, 0]
            votes = np.sum(np.abs(p[sample] @ n.T - np.sum(n * a, axis=1)) <= tol[sample, None], axis=0)
            j = int(np.argmax(votes))
            if votes[j] > best_n:
                best, best_n = (n[j], a[j]), int(votes[j])
        if best is None:
            break
        inl = idx[np.abs((p[idx] - best[1]) @ best[0]) <= tol[idx]]
        if len(inl) < max(3, min_fraction * len(idx)):
            break
        c = p[inl].mean(0)  # least squares: the plane through the inliers' centroid, normal of least spread
        axes = np.linalg.svd(p[inl] - c, full_matrices=False)[2]
        d = np.abs((p[idx] - c) @ axes[2]) / tol[idx]
        inl = idx[d <= 1]
        if len(inl) < max(3, min_fraction * len(idx)) or np.sqrt(np.mean(d[d <= 1] ** 2)) > max_spread:
            break
        q = (p[inl] - c) @ axes[:2].T  # in-plane coordinates
        lo, span = q.min(0), np.maximum(np.ptp(q, axis=0), 1e-9)
        cell = np.minimum(((q - lo) / span * 16).astype(np.int64), 15)
        if len(np.unique(cell[:, 0] * 16 + cell[:, 1])) < min_cover * 256:
            break
        keep[inl] = False
    return keep


def _check_sampling(near: float, far: float, max_points: int, source: str) -> None:
    if not (np.isfinite(near) and np.isfinite(far) and 0 <= near < far):
        raise DepthError(f"{source}: near/far range must satisfy 0 <= near < far, got near={near}, far={far}")
    if max_points < 1:
        raise DepthError(f"{source}: max_points must be >= 1, got {max_points}")


def _off_planes_enough(pts, idx, min_points: int, count: int, tolerance: float, seed: int, source: str,
                       kept: str) -> np.ndarray:
    """The steps both cloud builders share once they know their candidate points
    ``pts[idx]``: drop the ``count`` largest planes (:func:`off_planes`), then require
    ``min_points`` left (``kept`` says how they were kept, for the error)."""
    if isinstance(count, bool) or not isinstance(count, (int, np.integer)) or count < 0:
        raise DepthError(f"{source}: remove_planes must be an integer >= 0, got {count!r}")
    if not (np.isfinite(tolerance) and tolerance >= 0):
        raise DepthError(f"{source}: plane_tolerance must be a finite number >= 0 (metres), got {tolerance!r}")
    if count:
        idx = idx[off_planes(pts[idx], count, tolerance, seed=seed)]
    if len(idx) < min_points:
        raise DepthError(f"{source}: only {len(idx)} points {kept}; at least {min_points} are needed")
    return idx


def _planes_note(count: int) -> str:
    return f", {count} largest plane{'s' if count > 1 else ''} removed" if count else ""


def _subsample(pts: np.ndarray, idx: np.ndarray, max_points: int, seed: int) -> Cloud:
    """The points ``pts[idx]`` as a :class:`Cloud` of ``max_points``: a seeded random
    subset when there are more, weight-0 padding when fewer."""
    if len(idx) > max_points:
        rng = np.random.default_rng(seed)
        idx = np.sort(rng.choice(idx, max_points, replace=False))
    out = np.zeros((max_points, 3), np.float32)
    w = np.zeros(max_points, np.float32)
    out[: len(idx)] = pts[idx]
    w[: len(idx)] = 1.0
    return Cloud(out, w)


def sensor_points_to_cloud(
    points: np.ndarray,
    near: float = 0.3, far: float = 8.0,
    max_points: int = 1024, seed: int = 0, min_points: int = 50,
    source: str = "point cloud",
    remove_planes: int = 0, plane_tolerance: float = 0.02,
    return_indices: bool = False,
):
    """Points in the sensor's frame (``(M, 3)``, metres; at the origin, looking
    along +z) -> fixed-size :class:`Cloud`, the counterpart of :func:`depth_to_cloud`.

    Keeps the finite points with ``near <= z <= far``, without the points of the
    ``remove_planes`` largest planes (:func:`off_planes`), then a deterministic
    random subset of ``max_points`` (the same sampling as :func:`depth_to_cloud`,
    so the foreground pixels of a depth image written out as points give the same
    cloud).  With ``return_indices``: ``(cloud, kept)``, the indices of every point
    kept before the subsampling.  Raises :class:`DepthError` when no point is
    finite, none lies within the range, fewer than ``min_points`` remain, or they
    all coincide."""
    with np.errstate(over="ignore"):  # beyond float32: inf, dropped below
        pts = np.asarray(points, np.float32)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise DepthError(f"{source}: expected points of shape (M, 3), got {pts.shape}")
    _check_sampling(near, far, max_points, source)
    finite = np.all(np.isfinite(pts), -1)
    if not finite.any():
        raise DepthError(f"{source}: the cloud holds no point (every point is NaN or inf)")
    z = pts[:, 2]
    with np.errstate(invalid="ignore"):
        keep = finite & (z >= near) & (z <= far)
    if not keep.any():
        zf = z[finite]
        hint = ("the cloud's unit and its viewpoint" if np.median(zf) > 0 else
                "most points lie behind the sensor: for a cloud in the OpenGL convention (y up, z towards the "
                "viewer) give --viewpoint 0,0,0,0,1,0,0")
        raise DepthError(
            f"{source}: no point lies within near={near} m .. far={far} m in front of the sensor "
            f"(the points' z spans {float(zf.min()):.4g} .. {float(zf.max()):.4g}; check the near/far range, "
            f"{hint})"
        )
    idx = _off_planes_enough(pts, np.flatnonzero(keep), min_points, remove_planes, plane_tolerance, seed, source,
                             f"lie within near={near} m .. far={far} m{_planes_note(remove_planes)}")
    if float(np.max(np.ptp(pts[idx], axis=0))) < 1e-3:
        raise DepthError(f"{source}: the points all lie within 1 mm of each other; not a cloud to fit")
    cloud = _subsample(pts, idx, max_points, seed)
    return (cloud, idx) if return_indices else cloud


def cloud_view(points: np.ndarray, width: int = 640, height: int = 480) -> tuple[np.ndarray, Intrinsics]:
    """A depth image of sensor-frame points, seen from the sensor, for plots: the
    intrinsics frame the points (5% margin, square pixels) and each pixel holds
    the nearest point's depth (NaN where none; one pass fills single-pixel gaps)."""
    p = np.asarray(points, np.float64)
    p = p[np.all(np.isfinite(p), -1) & (p[:, 2] > 1e-6)]
    depth = np.full((height, width), np.nan, np.float32)
    if len(p) == 0:
        return depth, Intrinsics(1.0, 1.0, width / 2, height / 2, width, height)
    uv = p[:, :2] / p[:, 2:3]
    lo, hi = uv.min(0), uv.max(0)
    span = np.maximum(hi - lo, 1e-6) * 1.1
    f = float(min(width / span[0], height / span[1]))
    mid = (lo + hi) / 2
    k = Intrinsics(f, f, width / 2 - f * mid[0], height / 2 - f * mid[1], width, height)
    u = np.clip(np.round(f * uv[:, 0] + k.cx).astype(np.int64), 0, width - 1)
    v = np.clip(np.round(f * uv[:, 1] + k.cy).astype(np.int64), 0, height - 1)
    flat = np.full(height * width, np.inf)
    np.minimum.at(flat, v * width + u, p[:, 2])
    img = flat.reshape(height, width)
    pad = np.pad(img, 1, constant_values=np.inf)
    near = np.min([pad[1 + dy:1 + dy + height, 1 + dx:1 + dx + width] for dy in (-1, 0, 1) for dx in (-1, 0, 1)], 0)
    img = np.where(np.isfinite(img), img, near)
    depth[np.isfinite(img)] = img[np.isfinite(img)]
    return depth, k


def points_to_cloud(points: np.ndarray, max_points: int | None = None, seed: int = 0) -> Cloud:
    """An ``(N, 3)`` array of finite points -> :class:`Cloud` (subsampled/padded to ``max_points``)."""
    pts = np.asarray(points, np.float32).reshape(-1, 3)
    pts = pts[np.all(np.isfinite(pts), -1)]
    n = len(pts) if max_points is None else max_points
    if len(pts) > n:
        pts = pts[np.sort(np.random.default_rng(seed).choice(len(pts), n, replace=False))]
    out = np.zeros((n, 3), np.float32)
    w = np.zeros(n, np.float32)
    out[: len(pts)] = pts
    w[: len(pts)] = 1.0
    return Cloud(out, w)


def project(points: np.ndarray, k: Intrinsics) -> np.ndarray:
    """Camera-frame points ``(..., 3)`` -> pixel coordinates ``(..., 2)`` (u, v)."""
    p = np.asarray(points, np.float64)
    z = np.where(np.abs(p[..., 2]) > 1e-9, p[..., 2], 1e-9)
    return np.stack([k.fx * p[..., 0] / z + k.cx, k.fy * p[..., 1] / z + k.cy], -1)
