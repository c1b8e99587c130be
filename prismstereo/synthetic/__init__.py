"""Synthetic bi-prism captures with exact ground truth: textures, scenes and the renderer."""

from prismstereo.synthetic.lens import (
    apparent_depth,
    blur_circle_px,
    defocus_blur,
    fresnel_transmittance,
    prism_transmittance,
)
from prismstereo.synthetic.photo_scenes import HeightField, disparity_scene, height_field_scene, middlebury_scene
from prismstereo.synthetic.render import Capture, ImageFormation, render, render_radiance
from prismstereo.synthetic.scenes import (
    Hit,
    Plane,
    Scene,
    Sphere,
    Surface,
    fronto_parallel_plane,
    slanted_plane,
    sphere_scene,
    step_scene,
)
from prismstereo.synthetic.targets import calibration_views, charuco_target, checkerboard_target, circle_grid_target
from prismstereo.synthetic.textures import (
    CheckerTexture,
    CircleGridTexture,
    ConstantTexture,
    ImageTexture,
    NoiseTexture,
    SceneError,
    Texture,
    feature_size_for_depth,
)

__all__ = [
    "Capture",
    "ImageFormation",
    "render",
    "render_radiance",
    "apparent_depth",
    "blur_circle_px",
    "defocus_blur",
    "fresnel_transmittance",
    "prism_transmittance",
    "HeightField",
    "Hit",
    "Plane",
    "Scene",
    "Sphere",
    "Surface",
    "calibration_views",
    "charuco_target",
    "checkerboard_target",
    "circle_grid_target",
    "disparity_scene",
    "fronto_parallel_plane",
    "height_field_scene",
    "middlebury_scene",
    "slanted_plane",
    "sphere_scene",
    "step_scene",
    "CheckerTexture",
    "CircleGridTexture",
    "ConstantTexture",
    "ImageTexture",
    "NoiseTexture",
    "SceneError",
    "Texture",
    "feature_size_for_depth",
]
