"""Epipolar geometry of the bi-prism.

The depth model's path: the exact plane sweep as a Chebyshev interpolant (:mod:`~prismstereo.epipolar.sweep`),
its power series and tables for the fine bands (:mod:`~prismstereo.epipolar.table`), and the row rectification
fitted to it for the coarse level (:mod:`~prismstereo.epipolar.row_rectify`). Beside it, for analysis and other
tools: the thesis' lines and the exact curves (:mod:`~prismstereo.epipolar.lines`), sampling grids and shift
bands (:mod:`~prismstereo.epipolar.grids`); the pinhole rectification of the virtual cameras
(:mod:`prismstereo.epipolar.rectify`, approximate, not exported here).
"""

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
from prismstereo.epipolar.row_rectify import RowRectification, fit_row_rectification, rectified_level
from prismstereo.epipolar.sweep import (
    SweepFit,
    depth_to_sweep,
    fit_sweep,
    sweep_coefficients,
    sweep_positions,
    sweep_to_depth,
)
from prismstereo.epipolar.table import (
    column_to_sweep,
    series_at,
    series_band,
    sweep_hypotheses,
    sweep_series,
    tabulate_sweep,
    valid_interval,
)

__all__ = [
    "SweepFit",
    "depth_to_sweep",
    "fit_sweep",
    "sweep_coefficients",
    "sweep_positions",
    "sweep_to_depth",
    "column_to_sweep",
    "series_at",
    "series_band",
    "sweep_hypotheses",
    "sweep_series",
    "tabulate_sweep",
    "valid_interval",
    "RowRectification",
    "fit_row_rectification",
    "rectified_level",
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
