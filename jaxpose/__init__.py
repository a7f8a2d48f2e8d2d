"""jaxpose: the pose of an arbitrary kinematic skeleton from a single depth image or point cloud.

The pure functional core (usable inside your own ``jax.jit``/``jax.vmap``):

- skeletons: :class:`Skeleton`, :class:`Pose`, :func:`rest_pose`
- the genome: :func:`genome_layout`, :func:`genome_bounds`, :func:`encode`, :func:`decode`
- kinematics: :func:`forward_kinematics` -> :class:`Links`, :func:`collision_pairs`
- objective: :class:`Cloud`, :class:`ObjectiveConfig`, :func:`paper_cost`, :func:`data_cost`,
  :func:`population_cost`, :func:`observe`, :func:`cloud_spread`
- search: :func:`fit` (pure), :func:`fit_batch` (sharded over devices), :func:`fit_cloud`, :class:`Fitter`,
  :class:`FitConfig` (static settings),
  :class:`FitParams` (traced settings), :class:`FitResult`, :class:`BranchSwapGA`, :class:`BoundedHillClimbing`
- tracking: :func:`track` (pure, one ``lax.scan`` over frames), :class:`Tracker` (live),
  :class:`TrackConfig`
- depth: :class:`Intrinsics`, :data:`KINECT_V1`, :func:`depth_to_cloud`, :func:`points_to_cloud`,
  :func:`sensor_points_to_cloud`

The edges (files): :func:`load_skeleton` (native TOML/JSON, URDF, MJCF), :func:`load_depth`,
:func:`load_points` (PLY, PCD, XYZ, NumPy point clouds), :func:`parse_intrinsics`, :func:`fit_file`.
Errors for bad input derive from :class:`JaxposeError`.
"""

__version__ = "0.1.0"

from ._xla_flags import disable_ynn_fusions as _disable_ynn_fusions

_disable_ynn_fusions()  # before anything computes: see jaxpose/_xla_flags.py

from .distributed import initialize_from_environment as _initialize_from_environment

_initialize_from_environment()  # JAXPOSE_DISTRIBUTED=1: join a multi-process run (jaxpose/distributed.py)

from .camera import KINECT_V1, Intrinsics, depth_to_cloud, points_to_cloud, project, sensor_points_to_cloud
from .errors import ConfigError, DepthError, IntrinsicsError, JaxposeError, SkeletonError
from .genome import decode, encode, genome_bounds, genome_layout
from .io.cloud_file import load_points, to_sensor_frame
from .io.depth_file import load_depth, parse_intrinsics
from .io.skeleton_file import load_skeleton, shipped_skeletons
from .kinematics import Links, collision_pairs, forward_kinematics
from .objective import Cloud, ObjectiveConfig, cloud_spread, data_cost, observe, paper_cost, population_cost
from .parallel import fit_batch
from .pipeline import InputOptions, fit_file
from .search import BoundedHillClimbing, BranchSwapGA, FitConfig, FitParams, Fitter, FitResult, fit, fit_cloud
from .skeleton import Pose, Skeleton, rest_pose
from .tracking import TrackConfig, Tracker, track

__all__ = [
    "KINECT_V1", "BoundedHillClimbing", "BranchSwapGA", "Cloud", "ConfigError", "DepthError", "FitConfig",
    "FitParams", "FitResult", "Fitter", "InputOptions", "Intrinsics", "IntrinsicsError", "JaxposeError", "Links",
    "ObjectiveConfig", "Pose", "Skeleton", "SkeletonError", "cloud_spread", "collision_pairs", "data_cost", "decode",
    "depth_to_cloud", "encode", "fit", "fit_batch", "fit_cloud", "fit_file", "forward_kinematics", "genome_bounds",
    "genome_layout", "load_depth", "load_points", "load_skeleton", "observe", "paper_cost", "parse_intrinsics",
    "points_to_cloud", "population_cost", "project", "rest_pose", "sensor_points_to_cloud", "shipped_skeletons",
    "to_sensor_frame", "TrackConfig", "Tracker", "track",
]
