"""File-level conveniences: depth image or point-cloud file + skeleton file -> fit result (an edge module)."""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass

import numpy as np

from .camera import Intrinsics, cloud_view, depth_to_cloud, sensor_points_to_cloud
from .errors import ConfigError, DepthError, InputWarning, require_finite, require_integer
from .io.cloud_file import is_cloud_file, load_points, parse_viewpoint, to_sensor_frame
from .io.depth_file import parse_intrinsics, read_depth
from .io.fit_result import file_sha256, result_document
from .io.skeleton_file import ROBOT_EXTENSIONS, load_skeleton, resolve_skeleton_path
from .objective import Cloud, cloud_spread
from .search import FitConfig, FitResult, fit_cloud
from .skeleton import Skeleton


MAX_PLANES = 8
MAX_POINTS = 1_000_000  # points sampled from one input at most


@dataclass(frozen=True)
class InputOptions:
    """How a depth image or point-cloud file becomes a cloud, each setting documented
    below its field: for depth images, for point clouds, or for both.  See docs/input.md."""

    intrinsics: str | None = "kinect"
    """Depth images: the camera (``kinect``, ``fx,fy,cx,cy`` or a JSON file:
    :func:`~jaxpose.io.depth_file.parse_intrinsics`)."""
    depth_scale: float = 0.001
    """Depth images: metres per stored integer."""
    near: float = 0.3
    """Both: the nearest depth kept (metres along the sensor's z)."""
    far: float = 8.0
    """Both: the farthest depth kept (metres along the sensor's z)."""
    background: str | None = None
    """Depth images: an image of the scene without the subject, subtracted."""
    background_tolerance: float = 0.05
    """Depth images: how far in front of the background (metres, plus the depth
    noise) a pixel must lie to be kept."""
    max_points: int = 1024
    """Both: the cloud's size (a seeded random subset, or padding)."""
    sample_seed: int = 0
    """Both: the seed of that subset."""
    cloud_scale: float = 1.0
    """Point clouds: metres per unit of the file's coordinates."""
    viewpoint: tuple | str | None = None
    """Point clouds: ``tx,ty,tz,qw,qx,qy,qz``, the sensor's pose in the cloud's frame,
    the translation in the file's unit like a PCD ``VIEWPOINT``; ``None``: the
    file's own, identity unless a PCD header gives one."""
    remove_planes: int = 0
    """Both: drop the points of that many largest planes, a floor or a wall
    (:func:`~jaxpose.camera.off_planes`)."""
    plane_tolerance: float = 0.02
    """Both: how far from a plane (metres, plus the depth noise) a point lies on it."""

    def validate(self) -> "InputOptions":
        """Raise :class:`ConfigError` for an impossible setting; return ``self``."""
        near, far = require_finite("near", self.near), require_finite("far", self.far)
        if not 0 <= near < far:
            raise ConfigError(f"near {near} / far {far}: need 0 <= near < far (metres)")
        if not require_finite("depth_scale", self.depth_scale) > 0:
            raise ConfigError(f"depth_scale must be > 0 (metres per stored unit), got {self.depth_scale}")
        if not require_finite("cloud_scale", self.cloud_scale) > 0:
            raise ConfigError(f"cloud_scale must be > 0 (metres per unit of the cloud file), got {self.cloud_scale}")
        if self.viewpoint is not None:
            try:
                parse_viewpoint(self.viewpoint)
            except ValueError as e:
                raise ConfigError(f"viewpoint {self.viewpoint!r}: {e}") from None
        if require_finite("background_tolerance", self.background_tolerance) < 0:
            raise ConfigError(f"background_tolerance must be >= 0 metres, got {self.background_tolerance}")
        if require_finite("plane_tolerance", self.plane_tolerance) < 0:
            raise ConfigError(f"plane_tolerance must be >= 0 metres, got {self.plane_tolerance}")
        require_integer("max_points", self.max_points, 1)
        if self.max_points > MAX_POINTS:
            raise ConfigError(f"max_points must be <= {MAX_POINTS}, got {self.max_points}")
        require_integer("sample_seed", self.sample_seed, 0)
        if not 0 <= require_integer("remove_planes", self.remove_planes) <= MAX_PLANES:
            raise ConfigError(f"remove_planes must lie within 0 .. {MAX_PLANES}, got {self.remove_planes}")
        return self


@dataclass
class FitOutput:
    skeleton: Skeleton
    result: FitResult
    depth: np.ndarray
    intrinsics: Intrinsics
    document: dict


def load_observation(depth_path: str, options: InputOptions = InputOptions()):
    """Read and validate a depth file (and background); return ``(depth, intrinsics, cloud)``."""
    return read_observation(depth_path, options)[:3]


def read_observation(depth_path: str, options: InputOptions):
    """:func:`load_observation`, and whether the depth scale was applied (integer pixels
    in the depth image or its background)."""
    options.validate()
    depth, scaled = read_depth(depth_path, options.depth_scale)
    k = parse_intrinsics(options.intrinsics, depth.shape, image=str(depth_path))
    background = None
    if options.background:
        try:
            background, background_scaled = read_depth(options.background, options.depth_scale)
            scaled = scaled or background_scaled
        except DepthError as e:
            raise DepthError(f"background image {e}") from None
        if background.shape != depth.shape:
            (bh, bw), (h, w) = background.shape, depth.shape
            raise DepthError(
                f"background image {options.background}: is {bw}x{bh}, but the depth image {depth_path} is {w}x{h}"
            )
    cloud = depth_to_cloud(
        depth, k, options.near, options.far, background, options.max_points, options.sample_seed,
        background_tolerance=options.background_tolerance, source=depth_path,
        remove_planes=options.remove_planes, plane_tolerance=options.plane_tolerance,
    )
    return depth, k, cloud, scaled


def load_cloud_observation(cloud_path: str, options: InputOptions = InputOptions()):
    """Read a point-cloud file into the sensor's frame; return ``(view, intrinsics,
    cloud, record)``: a depth image of the kept points seen from the sensor and its
    intrinsics (for plots, :func:`~jaxpose.camera.cloud_view`), the fixed-size
    :class:`Cloud`, and what the result file records about the input."""
    options.validate()
    if options.background:
        raise ConfigError(f"background {options.background}: background subtraction is for depth images; "
                          f"{cloud_path} is a point cloud")
    pf = load_points(cloud_path)
    viewpoint = parse_viewpoint(options.viewpoint) if options.viewpoint is not None else pf.viewpoint
    pts = to_sensor_frame(pf.points, viewpoint) * np.float32(options.cloud_scale)  # the viewpoint: the file's unit
    cloud, kept = sensor_points_to_cloud(
        pts, options.near, options.far, options.max_points, options.sample_seed, source=cloud_path,
        remove_planes=options.remove_planes, plane_tolerance=options.plane_tolerance, return_indices=True,
    )
    view, k = cloud_view(pts[kept])
    record = {
        "cloud": os.path.basename(cloud_path),
        "cloud_sha256": file_sha256(cloud_path),
        "cloud_format": pf.format,
        "points_in_file": int(len(pf.points)),
        "cloud_scale": options.cloud_scale,
        "viewpoint": [float(v) for v in viewpoint],
        **_sampling_record(options, cloud),
    }
    return view, k, cloud, record


def check_input(path: str, options: InputOptions = InputOptions()) -> None:
    """Read and check one input (a depth image or a point cloud) as a fit would;
    raise the fit's error for a bad one."""
    if is_cloud_file(path):
        load_cloud_observation(path, options)
    else:
        load_observation(path, options)


def _depth_record(depth_path: str, options: InputOptions, k: Intrinsics, cloud: Cloud, scaled: bool) -> dict:
    """What the result file records about a depth-image input (``depth_scale``: ``None``
    when the pixels are metres already and the scale was not applied)."""
    return {
        "depth": os.path.basename(depth_path),
        "depth_sha256": file_sha256(depth_path),
        "background": os.path.basename(options.background) if options.background else None,
        "background_sha256": file_sha256(options.background),
        "intrinsics": {"fx": k.fx, "fy": k.fy, "cx": k.cx, "cy": k.cy, "width": k.width, "height": k.height},
        "depth_scale": options.depth_scale if scaled else None,
        **_sampling_record(options, cloud),
    }


def _sampling_record(options: InputOptions, cloud: Cloud) -> dict:
    """What the result file records, for either kind of input, about how the cloud was chosen."""
    return {
        "remove_planes": options.remove_planes,
        "plane_tolerance": options.plane_tolerance,
        "near": options.near,
        "far": options.far,
        "max_points": options.max_points,
        "points_used": int(np.sum(np.asarray(cloud.weights) > 0)),
        "sample_seed": options.sample_seed,
    }


SCALE_MARGIN = 1.5  # how far outside the skeleton's scale range a cloud's size is only warned about
# a held scale (a robot file's) has no range to absorb the pose: folded robots spread down to 0.67
# times their rest spread (docs/experiments.md, "The scale warning's margin")
HELD_SCALE_MARGIN = 1.5


def unused_depth_scale(options: InputOptions, scaled: bool, source: str) -> str | None:
    """A warning when a depth scale other than the default was given for an image (and
    background) whose pixels are floats (metres already, so the scale is not applied);
    ``None`` otherwise."""
    if scaled or options.depth_scale == InputOptions.depth_scale:
        return None
    return (f"{source}: the depth scale {options.depth_scale:g} was not applied: the image stores float "
            "depths, read as metres (the scale converts integer pixels, as in a 16-bit PNG)")


def scale_warning(skel: Skeleton, cloud: Cloud, source: str) -> str | None:
    """A warning when the cloud's size is far outside what the skeleton's scale range can
    explain (more than :data:`SCALE_MARGIN` times beyond it), usually a cloud in another unit
    than metres; ``None`` otherwise.

    The size is the cloud's RMS spread against the rest-pose model's (the scale the search
    starts from); a held scale (``scale_lo == scale_hi``) gets :data:`HELD_SCALE_MARGIN` more.
    The margin leaves room for poses and partial views and still catches
    millimetres read as metres (1000x) or a depth image written at 5000 units per metre and
    read as millimetres (5x) (see docs/experiments.md)."""
    from .rest_model import rest_model

    ratio = float(cloud_spread(cloud) / rest_model(skel).spread)
    lo, hi = float(skel.scale_lo), float(skel.scale_hi)
    margin = SCALE_MARGIN * (HELD_SCALE_MARGIN if lo == hi else 1.0)
    if lo / margin <= ratio <= hi * margin:
        return None
    return (f"{source}: the points spread {ratio:.3g} times as wide as skeleton {skel.name!r} at rest, far outside "
            f"its scale range {lo:g} .. {hi:g}, so the fit will sit at the range's edge; check the unit (a depth "
            "image's depth scale, a point cloud's cloud scale) and the skeleton")


def robot_max_capsules(skel_file: str | None, max_capsules: int | None, loaded_here: bool) -> int | None:
    """The capsules per link at most a robot file was loaded with: ``max_capsules`` if given, else
    the default when the file was ``loaded_here`` (``None``: not a robot file, or unknown: a
    :class:`Skeleton` object given without the setting)."""
    from .io.capsules import MAX_CAPSULES

    if skel_file is None or os.path.splitext(skel_file)[1].lower() not in ROBOT_EXTENSIONS:
        return None
    if max_capsules is not None:
        return int(max_capsules)
    return MAX_CAPSULES if loaded_here else None


def load_fit_skeleton(skeleton: str | Skeleton, search_lengths: bool = False,
                      max_capsules: int | None = None, search_scale: bool = False) -> tuple[Skeleton, str | None]:
    """The skeleton to fit and its file (``None`` for a :class:`Skeleton` object)."""
    if isinstance(skeleton, Skeleton):
        return skeleton, None
    skel_file = resolve_skeleton_path(str(skeleton))
    skel = load_skeleton(skel_file, search_lengths=search_lengths, max_capsules=max_capsules, search_scale=search_scale)
    return skel, skel_file


def fit_on_devices(cloud: Cloud, skel: Skeleton, seed: int, config: FitConfig, devices: int,
                   progress=None) -> FitResult:
    """:func:`~jaxpose.parallel.fit_islands` over this process's first ``devices`` devices
    with an integer seed, its wall time (compilation included on a first call) recorded."""
    import time

    import jax
    import jax.numpy as jnp

    from .parallel import device_mesh, fit_islands

    mesh = device_mesh(devices)  # one process here (several take the batches)
    t = time.perf_counter()
    result = jax.block_until_ready(fit_islands(cloud, skel, jax.random.key(seed), config, mesh, progress=progress))
    return result._replace(wall_time=jnp.float32(time.perf_counter() - t))


def fit_file(
    path: str,
    skeleton: str | Skeleton,
    config: FitConfig = FitConfig(),
    seed: int = 0,
    options: InputOptions = InputOptions(),
    progress=None,
    search_lengths: bool = False,
    skeleton_file: str | None = None,
    max_capsules: int | None = None,
    hypotheses: int = 1,
    time_budget: float | None = None,
    devices: int | None = None,
    search_scale: bool = False,
) -> FitOutput:
    """Fit a skeleton (file path, shipped name, or :class:`Skeleton`) to a depth image
    or a point-cloud file (``.ply``, ``.pcd``, ``.xyz``, an ``(N, 3)`` ``.npy``: see
    :mod:`jaxpose.io.cloud_file`; the result is then in the sensor's frame).

    ``search_lengths``, ``search_scale``: for a robot file given by path, search its capsule
    lengths, its global scale (see :func:`~jaxpose.io.skeleton_file.load_skeleton`), and ``max_capsules``: model each
    link by that many capsules at most (default: :data:`~jaxpose.io.capsules.MAX_CAPSULES`; for a
    :class:`Skeleton` object, the setting it was loaded with, for the record only).
    ``skeleton_file``: the file a :class:`Skeleton` object was loaded from
    (:func:`load_fit_skeleton`), for the record.  ``hypotheses > 1``: also the best
    distinct poses (:mod:`jaxpose.search.hypotheses`), under ``"hypotheses"`` in the document.
    ``time_budget``: seconds of search (:meth:`~jaxpose.search.Fitter.run`), recorded with
    the generations run under ``"time_budget"``.  ``devices``: split the fit's islands over
    this process's first ``devices`` devices (:func:`~jaxpose.parallel.fit_islands`; neither
    hypotheses nor a time budget then); ``None``: :func:`~jaxpose.search.fit_cloud` on one."""
    config.validate()
    if devices is not None and (hypotheses > 1 or time_budget is not None):
        raise ConfigError("hypotheses and time_budget need the fit on one device (devices=None), "
                          f"got devices={devices}")
    options.validate()
    skel, skel_file = load_fit_skeleton(skeleton, search_lengths, max_capsules, search_scale)
    skel_file = skel_file or skeleton_file
    config = config.for_skeleton(skel)  # the generations the fit runs, also in the result's record
    if is_cloud_file(path):
        depth, k, cloud, inputs = load_cloud_observation(path, options)
        frame, unused_scale = "sensor (the cloud's viewpoint; x right, y down, z forward), metres", None
    else:
        depth, k, cloud, scaled = read_observation(path, options)
        inputs, frame = _depth_record(path, options, k, cloud, scaled), None
        unused_scale = unused_depth_scale(options, scaled, str(path))
    notes = [w for w in (scale_warning(skel, cloud, str(path)), unused_scale) if w]
    for w in notes:
        warnings.warn(w, InputWarning, stacklevel=2)
    generations_run = [0]

    def report(gen, best, evals):
        generations_run[0] = gen
        if progress is not None:
            progress(gen, best, evals)

    if devices is None:
        result = fit_cloud(cloud, skel, seed, config, report, hypotheses, time_budget)
    else:
        result = fit_on_devices(cloud, skel, seed, config, devices, report)
    if not (np.isfinite(float(result.cost)) and np.all(np.isfinite(np.asarray(result.links.end)))):
        raise ConfigError(
            f"{path}: the fit of {skel.name!r} ended with a non-finite cost or pose; "
            "check the skeleton's ranges and the depth scale"
        )
    doc = result_document(skel, skel_file, result, config, seed, inputs, cloud)
    if frame:
        doc["frame"] = frame
    doc["skeleton"]["search_lengths"] = bool(search_lengths)
    doc["skeleton"]["search_scale"] = bool(search_scale)
    doc["skeleton"]["max_capsules"] = robot_max_capsules(skel_file, max_capsules, not isinstance(skeleton, Skeleton))
    if devices is not None:
        doc["timing"]["devices"] = int(devices)  # the fit's islands split over them
    if time_budget is not None:
        doc["time_budget"] = {"seconds": float(time_budget), "generations_run": generations_run[0]}
    doc["warnings"] = notes
    return FitOutput(skel, result, depth, k, doc)
