"""``prismstereo design``: the parameter a rig needs for a target depth error (thesis sec. 6.3)."""

from __future__ import annotations

import argparse

import torch

from prismstereo.geometry.presets import load_rig

__all__ = ["add_parser"]


def _cmd_design(args: argparse.Namespace) -> int:
    from prismstereo import analysis as an

    rig = load_rig(args.rig)
    varies = [args.vary] if args.vary else list(an.VARY)
    z, target, px = args.depth_mm, args.target_error_mm, args.disparity_px
    names = {"f": "focal length f", "alpha": "prism angle alpha", "T_o": "prism distance T_o",
             "T": "prism thickness T"}
    eqs = {"f": "6.39", "alpha": "6.42 + 6.46", "T_o": "6.47", "T": "6.46"}
    lines = [f"Design for a depth error of {target:g} mm at Z = {z:g} mm from a disparity error of {px:g} px "
             f"({px * rig.pixel_size_mm:g} mm) (thesis sec. 6.3)"]
    rigs = {"current": rig}
    for vary in varies:
        d = an.design(rig, target_error_mm=target, depth_mm=z, vary=vary, disparity_px=px)
        if vary == varies[0]:
            lines.append(f"  current rig: error {d.current_error[0]:.3f} mm (eq. 6.36), {d.current_error[1]:.3f} mm"
                         " (exact model)")
        u = d.unit
        lines += [
            f"  vary {names[vary]}" + ("  (back-plane half-width t_b kept)" if vary in ("alpha", "T") else ""),
            f"    current {d.current:.4f} {u}; closed form (eq. {eqs[vary]}) {d.closed_form:.4f} {u};"
            f" exact {d.exact:.4f} {u}",
            f"    closed form - exact = {d.difference:+.4f} {u} ({d.difference / d.exact:+.2%});"
            f" the closed-form design's exact error is {d.closed_form_error_exact:.3f} mm",
        ]
        if d.pixels is not None:
            p = d.pixels
            lines.append(f"    or keep the FOV (theta_vc {p.theta_vc:.4f} rad): sensor {p.width_px:.0f} x "
                         f"{p.height_px:.0f} px, {p.pixels:.0f} px per half-image (eq. 6.41)")
        if vary == "T":
            t = an.required_thickness(rig, z, target, px)
            lines.append(f"    rejected root T+ = {t.rejected:.1f} mm (> n Z / (n - 1) = "
                         f"{z * rig.refractive_index / (rig.refractive_index - 1):.1f} mm: past the object)")
        if d.exact_rig is not None:
            rigs[f"{vary} = {d.exact:.3f} {u}"] = d.exact_rig
    back = max(r.apex_distance_mm + r.prism_thickness_mm for r in rigs.values())
    depths = [v for v in args.curve_depths_mm if v > back] if args.curve_depths_mm else [
        v for v in (250.0, 500.0, 750.0, 1000.0, 1500.0, 2000.0, 3000.0) if v > back]
    curves = an.error_curves_of(rigs, depths, px)
    lines.append("Absolute depth error (mm) against depth: closed form (eq. 6.22) / exact model")
    lines.append("  " + f"{'depth (mm)':>10}" + "".join(f"  {name:>24}" for name in curves))
    for i, depth in enumerate(depths):
        cells = "".join(f"  {float(c.closed_form[i]):>11.3f} / {float(c.exact[i]):>10.3f}" for c in curves.values())
        lines.append(f"  {depth:10.1f}{cells}")
    print("\n".join(lines))
    if args.plot:
        from prismstereo.analysis.plots import plot_curves

        dense = torch.linspace(depths[0], depths[-1], 30, dtype=torch.float64)
        series, styles = {}, {}
        for name, c in an.error_curves_of(rigs, dense, px).items():
            series[f"{name} (exact)"], styles[f"{name} (exact)"] = (c.depth, c.exact), "-"
            series[f"{name} (eq. 6.22)"], styles[f"{name} (eq. 6.22)"] = (c.depth, c.closed_form), "--"
        ax = plot_curves(series, styles=styles, title=f"depth error of a {px:g} px disparity error")
        ax.axhline(target, color="k", lw=0.8, ls=":")
        ax.axvline(z, color="k", lw=0.8, ls=":")
        ax.figure.savefig(args.plot, dpi=120)
        print(f"wrote {args.plot}")
    return 0


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the command on the main parser's subcommands."""
    design = sub.add_parser("design", help="parameter needed for a target depth error (thesis sec. 6.3)")
    design.add_argument("--rig", default="thesis_setup1", help="rig JSON file or preset name")
    design.add_argument("--target-error-mm", type=float, required=True, help="wanted absolute depth error")
    design.add_argument("--depth-mm", type=float, required=True, help="depth at which the target must hold")
    design.add_argument("--vary", choices=("f", "alpha", "T_o", "T"), default=None,
                        help="the parameter to change (default: each in turn)")
    design.add_argument("--disparity-px", type=float, default=1.0, help="disparity error in pixels")
    design.add_argument("--curve-depths-mm", type=float, nargs="+", default=None,
                        help="depths of the printed error curves")
    design.add_argument("--plot", default=None, help="write the error-vs-depth curves to this image")
    design.set_defaults(func=_cmd_design)
