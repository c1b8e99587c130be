"""A calibration's report, as OpenCV users expect it: RMS and per-view errors, each parameter before and after
with its standard error, the views that are outliers; and a plot of the residuals per view."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import torch

from prismstereo.calibration.fit import CalibrationResult
from prismstereo.calibration.parameters import INFO, NAMES

__all__ = ["HINTS", "format_report", "plot_residuals"]

HINTS: dict[str, str] = {
    "focal_length_mm": "boards tilted 30-45 deg",
    "cx": "corners or scene texture near both halves' outer columns",
    "cy": "corners or scene texture near the top and bottom rows",
    "k1": "corners or matches far from the centre (a larger board, or scenes textured to the edges)",
    "k2": "corners or matches far from the centre (a larger board, or scenes textured to the edges)",
    "k3": "corners or matches in the image's corners",
    "p1": "corners or matches spread over the whole image",
    "p2": "corners or matches spread over the whole image",
    "prism_offset_x_mm": "scene texture along the split (the apex column) at several depths",
    "apex_distance_mm": "boards at two distances at least 200 mm apart",
    "prism_thickness_mm": "boards at two distances at least 200 mm apart",
    "alpha_deg": "boards at two distances at least 200 mm apart",
    "refractive_index": "boards at two distances at least 200 mm apart",
    "tilt_x_deg": "corners or matches over the whole height of the image",
    "tilt_y_deg": "boards tilted about y, or scenes at several depths",
    "roll_deg": "corners or matches over the whole height of the image",
}
"""For each rig parameter, the captures that determine it (the report's advice on weak parameters)."""


def format_report(result: CalibrationResult, view_names: Sequence[str] | None = None,
                  scene_names: Sequence[str] | None = None) -> str:
    """The report as text: summary line, parameter table (nominal, calibrated, change, standard error, share of
    the estimate that came from the views), per-view RMS of each half, and warnings.

    Args:
        result: :func:`~prismstereo.calibration.fit.calibrate_board`'s result.
        view_names: a name per input capture (e.g. file names), default its index.
        scene_names: a joint calibration's name per scene capture, default its index.

    Returns:
        Multi-line text.

    Example:
        >>> format_report(result).splitlines()[0]  # doctest: +SKIP
        'Calibrated from 12 views, 672 corners: RMS 0.103 px (corner noise 0.074 px), 9 iterations'
    """
    obs = result.observations
    board = bool(obs.left.any())  # a self-calibration's observations are matches in the right half
    points, missing = ("corners", "views without the board in both halves") if board else \
        ("matches", "captures without matches")
    names = list(view_names) if view_names is not None else [str(i) for i in range(max(result.views, default=-1) + 1)]
    lines = [f"Calibrated from {len(result.views)} views, {obs.uv.shape[0]} {points}: RMS {result.rms_px:.4f} px "
             f"(corner noise {result.sigma_px:.4f} px per coordinate), {result.iterations} iterations "
             f"({result.message})",
             "",
             f"{'parameter':<20} {'unit':<4} {'nominal':>12} {'calibrated':>12} {'change':>11} {'std error':>10} "
             f"{'from views':>10}"]
    for i, name in enumerate(NAMES):
        before, after = float(result.before[i]), float(result.after[i])
        unit = INFO[name].unit
        if name in result.free:
            share = float(result.data_share[i])
            lines.append(f"{name:<20} {unit:<4} {before:>12.6g} {after:>12.6g} {after - before:>+11.4g} "
                         f"{float(result.std_error[i]):>10.3g} {share:>9.0%}")
        else:
            why = "(unobservable)" if name in result.unobservable else "(fixed)"
            lines.append(f"{name:<20} {unit:<4} {before:>12.6g} {why:>14}")
    unc = result.depth_uncertainty
    parts = [f"{100 * float(s):.2f} % at {float(z):.0f} mm"
             for z, s in zip(unc.depth_mm, unc.relative_std, strict=True)]
    if len({p.split(" at ")[0] for p in parts}) == 1 and len(parts) > 1:  # one value: said once, with its depths
        parts = [f"{parts[0].split(' at ')[0]} from {float(unc.depth_mm[0]):.0f} to {float(unc.depth_mm[-1]):.0f} mm"]
    lines += ["", f"depth uncertainty from the calibration (1 sigma, fixed parameters at their tolerance): "
              f"{', '.join(parts)}"]
    lines += _depth_drivers(unc)
    lines += ["", f"{'view':<24} {'left RMS px':>11} {'right RMS px':>12}"]
    for k, v in enumerate(result.views):
        left, right = (f"{float(x):.4f}" if x == x else "-" for x in result.view_rms_px[k])
        flag = "  <- outlier" if v in result.outlier_views else ""
        lines.append(f"{names[v]:<24} {left:>11} {right:>12}{flag}")
    skipped = [names[i] for i in range(len(names)) if i not in result.views]
    if skipped:
        lines.append(f"{missing} (not used): {', '.join(skipped)}")
    for v in result.outlier_views:
        lines.append(f"warning: view {names[v]} has an outlier reprojection error (over 3x the median view's); "
                     "check its detection or remove it")
    for v in result.downweighted_views:
        lines.append(f"view {names[v]}'s error was an outlier after the first fit: the second weighted it down to the "
                     "median view's")
    if result.unobservable:
        lines.append(f"not observable from these captures, held at their nominal values: "
                     f"{', '.join(result.unobservable)}")
    if result.joint is not None:
        lines += _joint_lines(result, scene_names)
    if result.weak:
        lines.append(f"note: the views barely determine {', '.join(result.weak)} (under half of their estimate came "
                     "from the views; they stay near their nominal values within their tolerances). What would "
                     "determine them:")
        lines += [f"  {name}: {HINTS[name]}" for name in result.weak]
    return "\n".join(lines)


def _depth_drivers(unc) -> list[str]:
    """The parameters behind most of the depth uncertainty, and the captures that would determine them."""
    if unc.share is None or not bool(torch.isfinite(unc.share).all()) or float(unc.share.abs().sum()) == 0:
        return []
    order = [int(i) for i in unc.share.argsort(descending=True) if float(unc.share[i]) >= 0.1][:3]
    if not order:
        return []
    lines = ["knowing one parameter exactly would remove this share of the depth variance: "
             + ", ".join(f"{NAMES[i]} {float(unc.share[i]):.0%}" for i in order) + "; to determine them better:"]
    return lines + [f"  {NAMES[i]}: {HINTS[NAMES[i]]}" for i in order]


def _joint_lines(result: CalibrationResult, scene_names: Sequence[str] | None) -> list[str]:
    """A joint calibration's part of the report: each input's standard errors, the depth uncertainty each
    predicts, the scenes' fit."""
    joint = result.joint
    found = joint.contributions
    count = max(joint.scenes + joint.outlier_scenes) + 1
    names = list(scene_names) if scene_names is not None else [str(i) for i in range(count)]
    sets = found.names
    lines = ["", "what each input determines: standard error from each set with the priors (reported units; a "
                 "parameter a set does not see keeps its prior's)",
             f"{'parameter':<20} " + " ".join(f"{n:>10}" for n in sets)]
    for i, name in enumerate(NAMES):
        if name in result.free:
            lines.append(f"{name:<20} " + " ".join(f"{float(found.std_error[k, i]):>10.3g}" for k in range(len(sets))))
    depths = joint.predicted[-1].depth_mm
    lines.append(f"depth uncertainty each set predicts (1 sigma, {float(depths.min()):.0f}-{float(depths.max()):.0f} "
                 "mm): " + ", ".join(f"{n} {100 * float(u.relative_std.mean()):.3g} %"
                                     for n, u in zip(sets, joint.predicted, strict=True)))
    rms = ", ".join(f"{names[v]} {float(r):.3f}" for v, r in zip(joint.scenes, joint.scene_rms_px, strict=True))
    lines.append(f"scenes: {joint.matches} matches, RMS from their exact epipolar curves: {rms} px (match noise "
                 f"{joint.scene_sigma_px:.3f} px per coordinate)")
    for v in joint.outlier_scenes:
        lines.append(f"warning: scene {names[v]} was left out: its matches disagree with the boards and the other "
                     "scenes (over 3x the median scene's RMS: a moving object, or a capture of another rig?)")
    return lines


def plot_residuals(result: CalibrationResult, path: str | Path, view_names: Sequence[str] | None = None) -> None:
    """Save a figure of the residuals: per-view RMS of both halves (bars) and every corner's residual vector.

    Example:
        >>> plot_residuals(result, "residuals.png")  # doctest: +SKIP
    """
    from matplotlib.figure import Figure  # no pyplot: the caller's backend (e.g. a notebook's) stays as it is

    obs = result.observations
    names = list(view_names) if view_names is not None else [str(v) for v in result.views]
    if view_names is not None:
        names = [names[v] for v in result.views]
    fig = Figure(figsize=(12, 4.5))
    ax0, ax1 = fig.subplots(1, 2)
    x = range(len(result.views))
    ax0.bar([i - 0.2 for i in x], result.view_rms_px[:, 0].numpy(), 0.4, label="left (reference)")
    ax0.bar([i + 0.2 for i in x], result.view_rms_px[:, 1].numpy(), 0.4, label="right")
    ax0.axhline(result.rms_px, color="k", lw=0.8, ls="--", label=f"overall {result.rms_px:.3f} px")
    ax0.set_xticks(list(x), names, rotation=45, ha="right", fontsize=7)
    ax0.set_ylabel("RMS reprojection error (px)")
    ax0.set_title("per view and half")
    ax0.legend(fontsize=8)
    res = result.residuals.numpy()
    for half, mask, colour in (("left", obs.left, "C0"), ("right", ~obs.left, "C1")):
        m = mask.numpy()
        ax1.scatter(res[m, 0], res[m, 1], s=4, c=colour, label=half, alpha=0.6)
    ax1.set_aspect("equal")
    ax1.set_xlabel("du (px)")
    ax1.set_ylabel("dv (px)")
    ax1.set_title("corner residuals (projection - detection)")
    ax1.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(str(path), dpi=110)
