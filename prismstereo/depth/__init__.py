"""Depth from matching results: exact conversions between indices, disparities and metric depth, the z-buffer
occlusion test, point clouds of the reference view (and PLY files), and the depth range a rig can search."""

from prismstereo.depth.convert import depth_to_disparity, depth_to_index, disparity_to_depth, index_to_depth
from prismstereo.depth.occlusion import zbuffer_visible
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
    "zbuffer_visible",
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
