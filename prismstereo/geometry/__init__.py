"""Rig, exact prism optics (tracing and projection) and virtual cameras (thesis chapter 3)."""

from prismstereo.geometry.optics import (
    Half,
    RayBundle,
    apex_ray,
    check_rig_images,
    half_of_pixels,
    pixel_directions,
    points_at_depth,
    trace_directions,
    trace_pixels,
)
from prismstereo.geometry.parameters import RigParameters
from prismstereo.geometry.presets import load_rig, thesis_setup1, thesis_setup2
from prismstereo.geometry.projection import Projection, project_points, solve_projection
from prismstereo.geometry.rig import BiPrismRig
from prismstereo.geometry.surfaces import Refraction, refract
from prismstereo.geometry.virtual_camera import (
    VirtualCamera,
    VirtualCameraPair,
    closest_point_to_rays,
    pinhole_reprojection_error,
    ray_midpoint,
    virtual_camera,
    virtual_cameras,
)

__all__ = [
    "BiPrismRig",
    "RigParameters",
    "thesis_setup1",
    "thesis_setup2",
    "load_rig",
    "Half",
    "Projection",
    "RayBundle",
    "Refraction",
    "apex_ray",
    "check_rig_images",
    "half_of_pixels",
    "pixel_directions",
    "points_at_depth",
    "project_points",
    "solve_projection",
    "refract",
    "trace_directions",
    "trace_pixels",
    "VirtualCamera",
    "VirtualCameraPair",
    "closest_point_to_rays",
    "pinhole_reprojection_error",
    "ray_midpoint",
    "virtual_camera",
    "virtual_cameras",
]
