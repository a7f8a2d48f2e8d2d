"""File formats: skeletons, depth images, point clouds, intrinsics, atomic writes and JSON (the I/O edge)."""

from .atomic import atomic_write, write_json
from .cloud_file import load_points
from .depth_file import load_depth, parse_intrinsics, save_depth_png
from .skeleton_file import load_skeleton, shipped_skeletons, skeleton_from_dict

__all__ = [
    "atomic_write", "load_depth", "load_points", "load_skeleton", "parse_intrinsics", "save_depth_png",
    "shipped_skeletons", "skeleton_from_dict", "write_json",
]
