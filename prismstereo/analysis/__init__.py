"""Field of view, depth error and design of a bi-prism rig (thesis chapters 5 and 6).

Every closed form of the thesis sits next to the exact ray-traced model it approximates:

* :mod:`~prismstereo.analysis.fov_formulas` (ch. 5): phi_2, phi_4, gamma, epsilon, FOV type and alpha_1 /
  alpha_2; :mod:`~prismstereo.analysis.fov`: a rig's Ray 1 / Ray 2 lines (with prism offsets) and extents;
  :mod:`~prismstereo.analysis.fov_exact`: the exact FOV by tracing a sensor row.
* :mod:`~prismstereo.analysis.error` (ch. 6.1-6.2): depth from disparity (eq. 6.15, the general form 6.9,
  the exact model), sensitivities (eq. 6.20-6.35 vs autograd), error budgets, where eq. 6.15 fails.
* :mod:`~prismstereo.analysis.design` (ch. 6.3): the f / pixel count, T, alpha or T_o that meets a target
  depth error, by the thesis' formulas and by root finding on the exact model.
* :mod:`~prismstereo.analysis.pinhole_rectify` (ch. 4): Fusiello rectification of the virtual pinholes and how
  far true correspondences stay off their rows (not exported here; the model rectifies with
  :mod:`prismstereo.epipolar.row_rectify`).
* :mod:`~prismstereo.analysis.plots`: the thesis' figures drawn from the above.
"""

from prismstereo.analysis._common import AnalysisError
from prismstereo.analysis.depth_models import (
    ExactDepth,
    StereoPair,
    depth_exact,
    depth_planar,
    depth_small_angle,
    disparity_mm,
    disparity_small_angle,
    project_pair,
)
from prismstereo.analysis.design import (
    VARY,
    Design,
    PixelDesign,
    ThicknessDesign,
    Vary,
    closed_form_error,
    design,
    error_curves_of,
    required_apex_distance,
    required_focal_length,
    required_pixels,
    required_thickness,
)
from prismstereo.analysis.error import (
    ErrorBudget,
    ErrorCurves,
    Sensitivities,
    SmallAngleCheck,
    Uncertainties,
    closed_form_sensitivities,
    error_budget,
    error_curves,
    exact_dz_dd,
    exact_sensitivities,
    small_angle_check,
)
from prismstereo.analysis.fov import FOVClosedForm, FOVExtent, RayLine, fov_closed_form, fov_extent
from prismstereo.analysis.fov_exact import (
    FOVComparison,
    FOVSweep,
    compare_fov,
    exact_fov_extent,
    exact_fov_type,
    fov_alpha_sweep,
)
from prismstereo.analysis.fov_formulas import (
    FOV_TYPES,
    BoundaryAngles,
    FOVType,
    boundary_angles,
    common_fov_angle,
    fov_coefficient,
    fov_type,
    offset_shift,
    ray1_angle,
    ray1_intercept,
    ray2_angle,
    ray2_intercept,
)

__all__ = [
    "AnalysisError",
    # fov
    "FOVType",
    "FOV_TYPES",
    "RayLine",
    "BoundaryAngles",
    "FOVClosedForm",
    "FOVExtent",
    "FOVComparison",
    "FOVSweep",
    "ray1_angle",
    "ray2_angle",
    "ray1_intercept",
    "ray2_intercept",
    "common_fov_angle",
    "fov_coefficient",
    "fov_type",
    "boundary_angles",
    "offset_shift",
    "fov_closed_form",
    "fov_extent",
    "exact_fov_extent",
    "exact_fov_type",
    "compare_fov",
    "fov_alpha_sweep",
    # error
    "StereoPair",
    "ExactDepth",
    "Sensitivities",
    "Uncertainties",
    "ErrorBudget",
    "SmallAngleCheck",
    "ErrorCurves",
    "disparity_mm",
    "project_pair",
    "depth_small_angle",
    "disparity_small_angle",
    "depth_planar",
    "depth_exact",
    "closed_form_sensitivities",
    "exact_sensitivities",
    "exact_dz_dd",
    "error_budget",
    "error_curves",
    "small_angle_check",
    # design
    "Vary",
    "VARY",
    "PixelDesign",
    "ThicknessDesign",
    "Design",
    "closed_form_error",
    "required_focal_length",
    "required_pixels",
    "required_thickness",
    "required_apex_distance",
    "design",
    "error_curves_of",
]
