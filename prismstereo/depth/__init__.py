"""Depth from matching results: exact conversions between indices, disparities and metric depth, the models' result
(:class:`DepthResult`) and its maps brought to full resolution (:func:`upsample`), point clouds of the reference view
(and PLY files), and the depth range a rig can search."""

from prismstereo.depth.convert import depth_to_disparity, depth_to_index, disparity_to_depth, index_to_depth
from prismstereo.depth.points import PointCloud, PointCloudError, depth_to_points, read_ply, write_ply
from prismstereo.depth.range import (
    DepthRangeError,
    back_plane_depth,
    check_z_range,
    covisible_fraction,
    default_z_range,
)
from prismstereo.depth.resample import upsample
from prismstereo.depth.result import DepthResult

__all__ = [
    "DepthResult",
    "upsample",
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
