"""Depth from matching results: exact conversions between indices, disparities and metric depth, point clouds
of the reference view (and PLY files), and the depth range a rig can search."""

from prismstereo.depth.convert import depth_to_disparity, depth_to_index, disparity_to_depth, index_to_depth
from prismstereo.depth.points import PointCloud, PointCloudError, depth_to_points, read_ply, write_ply
from prismstereo.depth.range import (
    DepthRangeError,
    back_plane_depth,
    check_z_range,
    covisible_fraction,
    default_z_range,
)

__all__ = [
    "depth_to_disparity",
    "depth_to_index",
    "disparity_to_depth",
    "index_to_depth",
    "PointCloud",
    "PointCloudError",
    "depth_to_points",
    "read_ply",
    "write_ply",
    "DepthRangeError",
    "back_plane_depth",
    "check_z_range",
    "covisible_fraction",
    "default_z_range",
]
