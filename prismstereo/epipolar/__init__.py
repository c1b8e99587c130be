"""Epipolar geometry of the bi-prism: thesis lines, exact curves, rectification and sampling grids."""

from prismstereo.epipolar.grids import (
    BandResidual,
    SamplingGrid,
    ShiftBands,
    band_residual,
    bands_for_tolerance,
    depth_hypotheses,
    exact_sampling_grid,
    normalise_right_grid,
    shift_bands,
)
from prismstereo.epipolar.lines import (
    EpipolarAccuracy,
    EpipolarLines,
    epipolar_line_accuracy,
    exact_epipolar_curve,
    exact_infinity_point,
    fundamental_epipolar_lines,
    fundamental_matrix,
    point_line_distance,
    projection_matrix,
    thesis_epipolar_lines,
)

__all__ = [
    "BandResidual",
    "SamplingGrid",
    "ShiftBands",
    "band_residual",
    "bands_for_tolerance",
    "depth_hypotheses",
    "exact_sampling_grid",
    "normalise_right_grid",
    "shift_bands",
    "EpipolarAccuracy",
    "EpipolarLines",
    "epipolar_line_accuracy",
    "exact_epipolar_curve",
    "exact_infinity_point",
    "fundamental_epipolar_lines",
    "fundamental_matrix",
    "point_line_distance",
    "projection_matrix",
    "thesis_epipolar_lines",
]
