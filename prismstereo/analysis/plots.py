"""Figure-style plots of chapters 5 and 6: top view of the FOV, phi_2 / phi_4 against alpha, error curves.

Each function draws on a given matplotlib ``Axes`` (or on a new figure made without pyplot, so it works
headless) and returns the axes; ``ax.figure.savefig(path)`` writes it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import torch

from prismstereo.analysis._common import AnalysisError
from prismstereo.analysis.fov import fov_closed_form, fov_extent
from prismstereo.analysis.fov_exact import exact_fov_extent
from prismstereo.analysis.fov_formulas import boundary_angles, ray1_angle, ray2_angle
from prismstereo.geometry.rig import BiPrismRig

__all__ = ["new_axes", "plot_fov_top_view", "plot_fov_angles", "plot_curves"]


def new_axes(figsize: tuple[float, float] = (7.0, 5.0)) -> Any:
    """A fresh ``Axes`` on a pyplot-free ``Figure`` (no display backend needed).

    Example:
        >>> new_axes((4.0, 3.0)).figure.get_size_inches().tolist()
        [4.0, 3.0]
    """
    from matplotlib.figure import Figure

    return Figure(figsize=figsize, layout="constrained").subplots()


def plot_fov_top_view(rig: BiPrismRig, depth_max_mm: float | None = None, ax: Any = None, exact: bool = True) -> Any:
    """Top view (thesis fig. 5.5-5.7, 5.12): the prism, each half's FOV wedge between its Ray 1 and Ray 2
    (closed form), the common FOV shaded, and exact common-FOV borders traced at a few depths.

    Args:
        rig: an untilted rig.
        depth_max_mm: last depth drawn (default: past the far end of a convergent FOV, else 2 m or past
            the Ray 1 / Ray 2 crossing).
        ax: axes to draw on (default a new figure).
        exact: also mark the exact (ray-traced) common-FOV borders.

    Returns:
        the axes.

    Example:
        >>> ax = plot_fov_top_view(thesis_setup1())
        >>> ax.figure.savefig("fov.png")  # doctest: +SKIP
    """
    fov = fov_closed_form(rig)
    z_b = float(fov.left_ray1.back_plane_z)
    if depth_max_mm is None:
        far, cross = float(fov.far_depth), float(fov.crossing_depth)
        depth_max_mm = 1.25 * far if math.isfinite(far) else max(2000.0, 1.5 * cross if math.isfinite(cross) else 0)
    if not math.isfinite(depth_max_mm) or depth_max_mm <= z_b:
        raise AnalysisError(f"depth_max_mm must be beyond the back plane ({z_b:.1f} mm), got {depth_max_mm}")
    ax = new_axes((7.0, 8.0)) if ax is None else ax
    d, t_o, half_w = rig.prism_offset_x_mm, rig.apex_distance_mm, rig.prism_width_mm / 2
    ax.fill([d - half_w, d, d + half_w], [z_b, t_o, z_b], color="lightblue", alpha=0.7, label="bi-prism")
    z = torch.linspace(z_b, depth_max_mm, 400, dtype=torch.float64)[1:]
    ext = fov_extent(fov, z)
    for k, (name, colour) in enumerate((("left (reference)", "tab:red"), ("right", "tab:green"))):
        bounds = ext.left if k == 0 else ext.right
        ax.fill_betweenx(z, bounds[:, 0], bounds[:, 1], color=colour, alpha=0.12, lw=0)
        ax.plot(bounds[:, 1 - k], z, color=colour, lw=1.5, label=f"{name} half: Ray 1")
        ax.plot(bounds[:, k], z, color=colour, lw=1.0, ls="--", label=f"{name} half: Ray 2")
    ax.fill_betweenx(z, ext.common[:, 0], ext.common[:, 1], where=ext.overlap, color="0.3", alpha=0.35,
                     lw=0, label="common FOV")
    if exact:
        zs = torch.linspace(z_b, depth_max_mm, 9, dtype=torch.float64)[1:]
        ex = exact_fov_extent(rig, zs)
        keep = ex.overlap
        ax.plot(ex.common[keep, 0], zs[keep], "k.", ms=6, label="exact common FOV (ray traced)")
        ax.plot(ex.common[keep, 1], zs[keep], "k.", ms=6)
    ax.plot([0.0], [0.0], "ks", label="real camera")
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("z (mm)")
    ax.set_title(f"{fov.fov_type} FOV\nalpha {rig.alpha_deg:g} deg, f {rig.focal_length_mm:g} mm, "
                 f"T_o {rig.apex_distance_mm:g} mm")
    ax.legend(loc="upper left", fontsize=8)
    return ax


def plot_fov_angles(
    n: float,
    sensor_width_mm: float,
    focal_length_mm: float,
    alpha_deg: Sequence[float] | torch.Tensor | None = None,
    ax: Any = None,
) -> Any:
    """phi_2 and phi_4 against the prism angle with alpha_1 and alpha_2 marked (thesis fig. 5.4).

    Example:
        >>> ax = plot_fov_angles(1.48, 4.7616, 25.0)
    """
    alphas = torch.linspace(0.5, 25.0, 200, dtype=torch.float64) if alpha_deg is None else torch.as_tensor(
        alpha_deg, dtype=torch.float64)
    a = torch.deg2rad(alphas)
    ax = new_axes() if ax is None else ax
    ax.plot(alphas, ray1_angle(a, n), label="phi_2 (Ray 1)")
    ax.plot(alphas, ray2_angle(a, n, sensor_width_mm, focal_length_mm), label="phi_4 (Ray 2)")
    b = boundary_angles(n, sensor_width_mm, focal_length_mm)
    for value, name, style in ((b.alpha1, "alpha_1", ":"), (b.alpha2, "alpha_2", "--")):
        ax.axvline(math.degrees(value), color="k", ls=style, lw=1, label=f"{name} = {math.degrees(value):.2f} deg")
    ax.axhline(0.0, color="0.5", lw=0.5)
    ax.set_xlabel("prism angle alpha (deg)")
    ax.set_ylabel("angle to the back-plane normal (rad)")
    ax.set_title(f"n {n:g}, sensor {sensor_width_mm:g} mm, f {focal_length_mm:g} mm")
    ax.legend(fontsize=8)
    return ax


def plot_curves(
    curves: Mapping[str, tuple[torch.Tensor, torch.Tensor]],
    ax: Any = None,
    xlabel: str = "depth Z (mm)",
    ylabel: str = "absolute depth error (mm)",
    title: str | None = None,
    styles: Mapping[str, str] | None = None,
) -> Any:
    """Line plot of named (x, y) curves, e.g. error against depth (thesis fig. 6.3-6.6, 6.12-6.14).

    Example:
        >>> ax = plot_curves({"a": (torch.tensor([1.0, 2.0]), torch.tensor([3.0, 4.0]))})
    """
    if not curves:
        raise AnalysisError("plot_curves needs at least one curve")
    ax = new_axes() if ax is None else ax
    for name, (x, y) in curves.items():
        style = (styles or {}).get(name, "-")
        ax.plot(torch.as_tensor(x).detach().cpu(), torch.as_tensor(y).detach().cpu(), style, label=name)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    if title:
        ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    return ax
