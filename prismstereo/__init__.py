"""prismstereo: metric stereo depth from one camera with a bi-prism, as differentiable torch layers.

The public API (conventions: :mod:`prismstereo.conventions`):

* rig: :class:`BiPrismRig`, :class:`RigParameters`, :func:`thesis_setup1`, :func:`thesis_setup2`,
  :func:`load_rig` (a rig file, JSON text, dict or preset name, geometry checked), :func:`check_rig_images`
* exact optics: :func:`trace_pixels`, :func:`project_points`, :func:`refract`, :func:`points_at_depth`
* virtual cameras (thesis ch. 3): :func:`virtual_camera`, :func:`virtual_cameras`
* depth: :class:`PrismStereo` (the model), :class:`DepthResult` (its output), :class:`DepthStream` (frames
  pushed one at a time); loaded on first use, so ``import prismstereo`` stays light
* errors: :class:`PrismStereoError` and its family
"""

import importlib

from prismstereo.errors import CalibrationError, OptionError, PrismStereoError, RigError, ShapeError
from prismstereo.geometry.optics import (
    RayBundle,
    Refraction,
    apex_ray,
    check_rig_images,
    half_of_pixels,
    pixel_directions,
    points_at_depth,
    refract,
    trace_directions,
    trace_pixels,
)
from prismstereo.geometry.presets import load_rig, thesis_setup1, thesis_setup2
from prismstereo.geometry.projection import Projection, project_points
from prismstereo.geometry.rig import BiPrismRig, RigParameters
from prismstereo.geometry.virtual_camera import (
    VirtualCamera,
    VirtualCameraPair,
    closest_point_to_rays,
    pinhole_reprojection_error,
    ray_midpoint,
    virtual_camera,
    virtual_cameras,
)

__version__ = "0.1.0"

__all__ = [
    "__version__",
    "PrismStereoError",
    "RigError",
    "ShapeError",
    "OptionError",
    "CalibrationError",
    "BiPrismRig",
    "RigParameters",
    "thesis_setup1",
    "thesis_setup2",
    "load_rig",
    "check_rig_images",
    "Projection",
    "RayBundle",
    "Refraction",
    "apex_ray",
    "half_of_pixels",
    "pixel_directions",
    "points_at_depth",
    "project_points",
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
    "PrismStereo",
    "DepthResult",
    "DepthStream",
]

_LAZY = {"PrismStereo": "prismstereo.model", "DepthResult": "prismstereo.model", "DepthStream": "prismstereo.stream"}


def __getattr__(name: str):
    """The depth model's names, imported on first use (PEP 562)."""
    if name in _LAZY:
        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'prismstereo' has no attribute {name!r}")
