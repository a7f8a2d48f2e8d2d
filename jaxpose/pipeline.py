"""File-level conveniences: depth file + skeleton file -> fit result (an edge module)."""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from .camera import Intrinsics, depth_to_cloud
from .io.depth_file import load_depth, parse_intrinsics
from .io.fit_result import file_sha256, result_document
from .io.skeleton_file import load_skeleton, resolve_skeleton_path
from .search import FitConfig, FitResult, fit_cloud
from .skeleton import Skeleton


@dataclass(frozen=True)
class DepthOptions:
    """How a depth file becomes a cloud."""

    intrinsics: str | None = "kinect"
    depth_scale: float = 0.001
    near: float = 0.3
    far: float = 8.0
    background: str | None = None
    background_tolerance: float = 0.05
    max_points: int = 1024
    sample_seed: int = 0


@dataclass
class FitOutput:
    skeleton: Skeleton
    result: FitResult
    depth: np.ndarray
    intrinsics: Intrinsics
    document: dict


def load_observation(depth_path: str, options: DepthOptions = DepthOptions()):
    """Read and validate a depth file (and background); return ``(depth, intrinsics, cloud)``."""
    depth = load_depth(depth_path, options.depth_scale)
    k = parse_intrinsics(options.intrinsics, depth.shape)
    background = load_depth(options.background, options.depth_scale) if options.background else None
    cloud = depth_to_cloud(
        depth, k, options.near, options.far, background, options.max_points, options.sample_seed,
        background_tolerance=options.background_tolerance, source=depth_path,
    )
    return depth, k, cloud


def fit_depth_file(
    depth_path: str,
    skeleton: str | Skeleton,
    config: FitConfig = FitConfig(),
    seed: int = 0,
    options: DepthOptions = DepthOptions(),
    progress=None,
) -> FitOutput:
    """Fit a skeleton (file path, shipped name, or :class:`Skeleton`) to a depth file."""
    config.validate()
    skel_file = None
    if isinstance(skeleton, Skeleton):
        skel = skeleton
    else:
        skel_file = resolve_skeleton_path(str(skeleton))
        skel = load_skeleton(skel_file)
    depth, k, cloud = load_observation(depth_path, options)
    result = fit_cloud(cloud, skel, seed, config, progress)
    inputs = {
        "depth": os.path.basename(depth_path),
        "depth_sha256": file_sha256(depth_path),
        "background": os.path.basename(options.background) if options.background else None,
        "background_sha256": file_sha256(options.background),
        "intrinsics": {"fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy, "width": k.width, "height": k.height},
        "depth_scale": options.depth_scale,
        "near": options.near,
        "far": options.far,
        "max_points": options.max_points,
        "points_used": int(np.sum(np.asarray(cloud.weights) > 0)),
        "sample_seed": options.sample_seed,
    }
    doc = result_document(skel, skel_file, result, config, seed, inputs)
    return FitOutput(skel, result, depth, k, doc)
