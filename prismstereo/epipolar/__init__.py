"""Epipolar geometry of the bi-prism.

The depth model's path: the exact plane sweep as a Chebyshev interpolant (:mod:`~prismstereo.epipolar.sweep`),
its truncated power series, which the fine bands sample through (:mod:`~prismstereo.epipolar.series`), its
table with local cubics, inversion and valid intervals (:mod:`~prismstereo.epipolar.sweep_table`), and the row
rectification fitted to it for the coarse level (:mod:`~prismstereo.epipolar.row_rectify`). Beside it, for
analysis and other tools: the thesis' lines and the exact curves (:mod:`~prismstereo.epipolar.lines`),
sampling grids and shift bands (:mod:`~prismstereo.epipolar.grids`). The pinhole rectification of the virtual
cameras (approximate, analysis only) is :mod:`prismstereo.analysis.pinhole_rectify`.
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
from prismstereo.epipolar.series import series_at, series_band, sweep_series
from prismstereo.epipolar.sweep import (
    SweepFit,
    depth_to_sweep,
    fit_sweep,
    sweep_coefficients,
    sweep_hypotheses,
    sweep_positions,
    sweep_to_depth,
)
from prismstereo.epipolar.sweep_table import column_to_sweep, tabulate_sweep, valid_interval

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
