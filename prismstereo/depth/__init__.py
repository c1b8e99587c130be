"""Depth from matching results: exact conversions between indices, disparities and metric depth."""

from prismstereo.depth.convert import depth_to_disparity, depth_to_index, disparity_to_depth, index_to_depth

__all__ = ["depth_to_disparity", "depth_to_index", "disparity_to_depth", "index_to_depth"]
