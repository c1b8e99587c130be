"""``prismstereo demo``: the main job on a built-in default: the rig, an exactness check of the optics, depth of a
rendered capture by the hybrid and the classical model."""

from __future__ import annotations

import argparse
from pathlib import Path

import torch

from prismstereo.cli.rig import show
from prismstereo.geometry.optics import points_at_depth, trace_pixels
from prismstereo.geometry.presets import load_rig
from prismstereo.geometry.projection import project_points
from prismstereo.geometry.rig import BiPrismRig

__all__ = ["add_parser"]


def _cmd_demo(args: argparse.Namespace) -> int:
    rig = load_rig(args.rig)
    print(show(rig))
    # Exactness check of the optics on the default rig: trace pixels, then project them back.
    gen = torch.Generator().manual_seed(0)
    uv = torch.rand(4096, 2, generator=gen, dtype=torch.float64)
    uv = uv * torch.tensor([rig.image_width - 1.0, rig.image_height - 1.0], dtype=torch.float64)
    rays = trace_pixels(rig, uv)
    print("Exact optics round trip (4096 random pixels, trace -> point at depth -> project_points)")
    for depth in (250.0, 525.0, 1374.0, 5000.0):
        pts = points_at_depth(rays, depth)
        worst = 0.0
        for half, mask in (("left", rays.left & rays.valid), ("right", ~rays.left & rays.valid)):
            proj = project_points(rig, pts[mask], half)
            worst = max(worst, float((proj.uv - uv[mask]).norm(dim=-1).max()))
        print(f"  depth {depth:6.0f} mm: max error {worst:.2e} px")
    if args.scale > 0:
        _demo_depth(rig, args.scale, Path(args.out))
    return 0


def _demo_depth(rig: BiPrismRig, scale: int, out: Path) -> None:
    """Render a step scene, run the hybrid and the classical depth model, print their errors, write the depth of
    the sensor's default (:func:`~prismstereo.models.default_kind`), its preview, the capture and its point cloud."""
    import numpy as np

    from prismstereo.depth.points import depth_to_points, write_ply
    from prismstereo.io import write_image
    from prismstereo.models import build_model, default_kind
    from prismstereo.preview import write_depth_preview
    from prismstereo.synthetic import ImageFormation, render, step_scene

    small = rig.downscaled(scale)
    near, far = 450.0, 650.0
    print(f"Depth from one capture (step scene {near:g}/{far:g} mm, sensor {small.image_width}x{small.image_height}"
          f" = 1/{scale} resolution, noise 1/255)")
    cap = render(small, step_scene(small, near, far), ImageFormation(supersample=2, noise_sigma=1 / 255))
    w = small.reference_width
    gt, cov = cap.depth[..., :w], cap.covisible[..., :w]
    results = {}
    default = default_kind(small)
    for name in ("hybrid", "classical"):
        model = build_model(small, name, (400.0, 700.0))
        with torch.inference_mode():
            res = results[name] = model(cap.image)
        ok = res.valid & cov
        rel = ((res.depth - gt).abs() / gt)[ok]
        line = model.summary() if name == "hybrid" else f"classical: {model.summary()}"  # the hybrid's names itself
        print(f"  {line}{' (the default on this sensor)' if name == default else ''}")
        print(f"    {ok.float().sum() / cov.float().sum():.1%} of co-visible pixels valid; relative depth error mean "
              f"{rel.mean():.3%}, median {rel.median():.3%}")
    res = results[default]
    out.mkdir(parents=True, exist_ok=True)
    depth = torch.where(res.valid, res.depth, torch.full_like(res.depth, float("nan")))
    np.save(out / "depth.npy", depth[0, 0].numpy().astype(np.float32))
    write_image(out / "capture.png", cap.image[0])
    write_depth_preview(out / "depth_preview.png", depth[0, 0])
    points = depth_to_points(small, depth.double(), res.valid)
    count = write_ply(out / "points.ply", points[0], res.valid[0, 0], colors=cap.image[0, :, :, :w])
    print(f"  wrote the default's {out}/depth.npy (mm, NaN invalid), depth_preview.png, capture.png, points.ply "
          f"({count} points)")


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register the command on the main parser's subcommands."""
    demo = sub.add_parser("demo", help="run the main job on a built-in default")
    demo.add_argument("--rig", default="thesis_setup1", help="rig JSON file or preset name")
    demo.add_argument("--scale", type=int, default=2,
                      help="run the depth part on a sensor this many times coarser (0 skips it)")
    demo.add_argument("--out", default="demo_output", help="output folder of the depth part")
    demo.set_defaults(func=_cmd_demo)
