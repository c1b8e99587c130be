"""``prismstereo fov``: the field of view's type, angles, border rays and common width (thesis ch. 5)."""

from __future__ import annotations

import argparse
import math

from prismstereo.errors import PrismStereoError
from prismstereo.geometry.presets import load_rig

__all__ = ["add_parser"]


def _cmd_fov(args: argparse.Namespace) -> int:
    from prismstereo import analysis as an

    rig = load_rig(args.rig)
    fov = an.fov_closed_form(rig)
    z_b = float(fov.left_ray1.back_plane_z)
    deg = math.degrees
    cross, far = float(fov.crossing_depth), float(fov.far_depth)
    lines = [
        "Field of view (thesis ch. 5; top view, camera frame: x right, z forward, mm)",
        f"  type                      {fov.fov_type}  (epsilon = phi4/phi2 = {float(fov.epsilon):.4f}, eq. 5.12)",
        f"  alpha                     {rig.alpha_deg:.3f} deg  (alpha1 {deg(fov.boundary.alpha1):.3f} deg: phi4 = phi2,"
        f" alpha2 {deg(fov.boundary.alpha2):.3f} deg: phi4 = 0)",
        f"  phi2  Ray 1 angle         {float(fov.phi2):.5f} rad  ({deg(float(fov.phi2)):.3f} deg, eq. 5.5)",
        f"  phi4  Ray 2 angle         {float(fov.phi4):+.5f} rad  ({deg(float(fov.phi4)):+.3f} deg, eq. 5.9)",
        f"  gamma common FOV angle    {float(fov.gamma):.5f} rad  ({deg(float(fov.gamma)):.3f} deg, eq. 5.10)",
        f"  h     Ray 1 intercept     {float(fov.h):.5f} mm  (eq. 5.16)",
        f"  v     Ray 2 intercept     {float(fov.v):.5f} mm  (eq. 5.25)",
        f"  Ray 2 crosses Ray 1 at    {f'Z = {cross:.1f} mm' if math.isfinite(cross) else 'never'}",
        f"  common FOV closes at      {f'Z = {far:.1f} mm' if math.isfinite(far) else 'never (open FOV)'}",
    ]
    if not fov.edge_rays_on_prism:
        lines.append("  warning: a sensor-edge ray misses the prism; the exact outer border is the prism's edge")
    lines.append(f"Border rays: x = x0 + (z - {z_b:.3f}) tan(theta), theta > 0 toward +x (eq. 5.17, 5.36-5.37)")
    for half in ("left", "right"):
        for k, role in ((1, "inner, apex"), (2, "outer, edge")):
            ray = getattr(fov, f"{half}_ray{k}")
            lines.append(f"  {half:<5} half  Ray {k} ({role})   x = {float(ray.intercept):+.5f} + (z - {z_b:.3f})"
                         f" * {math.tan(float(ray.angle)):+.6f}   (theta {float(ray.angle):+.5f} rad)")
    depths = [z for z in args.depth_mm if z > z_b]
    if not depths:
        raise PrismStereoError(f"--depth-mm values must be beyond the back plane ({z_b:.1f} mm)")
    cmp = an.compare_fov(rig, depths)
    lines.append("Common FOV (closed form vs exact ray trace of the principal row)")
    lines.append("  depth (mm)   width closed (mm)   width exact (mm)   worst border |diff| (mm)   exact x range (mm)")
    for i, z in enumerate(depths):
        lo, hi = cmp.exact.common[i].tolist()
        rng = f"[{lo:+.2f}, {hi:+.2f}]" if bool(cmp.exact.overlap[i]) else "none"
        lines.append(f"  {z:10.1f}   {float(cmp.closed_form.width[i]):17.3f}   {float(cmp.exact.width[i]):16.3f}"
                     f"   {float(cmp.difference[i]):24.2e}   {rng}")
    print("\n".join(lines))
    if args.plot:
        from prismstereo.analysis.plots import plot_fov_top_view

        ax = plot_fov_top_view(rig, args.plot_depth_mm)
        ax.figure.savefig(args.plot, dpi=120)
        print(f"wrote {args.plot}")
    return 0


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the command on the main parser's subcommands."""
    fov = sub.add_parser("fov", help="field of view: type, angles, border rays, common-FOV width (thesis ch. 5)")
    fov.add_argument("--rig", default="thesis_setup1", help="rig JSON file or preset name")
    fov.add_argument("--depth-mm", type=float, nargs="+", default=[500.0, 1000.0, 2000.0, 5000.0],
                     help="depths at which the common-FOV width is printed")
    fov.add_argument("--plot", default=None, help="write the top view (both FOVs, common region) to this image")
    fov.add_argument("--plot-depth-mm", type=float, default=None, help="last depth drawn in the plot")
    fov.set_defaults(func=_cmd_fov)
