"""ONNX parity at full resolution: the exported depth graph in onnxruntime against the torch model.

The unit tests (``tests/export``) check parity on a 128 x 96 sensor, where the fine band is one piece; at
1024 x 768 an exported band of more than 2 M voxels (``downsample=1``'s band of 11) runs in row strips, and a
batch-size dependence there once broke batch 4 in onnxruntime while every small test passed. This script renders
``thesis_setup1`` at full resolution (planes at 312 / 525 / 780 mm and a step 450 / 650 mm, 2 x 2 supersampling,
read noise 1/255, 8 bits), exports the wide-range model (228-1374 mm; the default, the pyramid, and also
``downsample=1``, ``downsample=2`` with block values and the fast full-resolution setting ``downsample=2,
full_band=1, band_edges='clamp'``), and
prints for batch 1 and batch 4 the largest and the 99.9th-percentile relative depth difference on pixels valid
in both, the number above 1e-4, the share of pixels whose valid flags agree and the largest confidence
difference. Targets (the ONNX issue): max relative difference <= 1e-4, valid masks agree on >= 99.9 %.

Run: .venv/bin/python benchmarks/onnx_parity.py [--scale K]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import torch

from prismstereo import thesis_setup1
from prismstereo.classical.model import PrismStereo
from prismstereo.export import OnnxDepth, export_onnx
from prismstereo.synthetic import ImageFormation, fronto_parallel_plane, render, step_scene
from prismstereo.threads import set_torch_threads

FORMATION = ImageFormation(supersample=2, noise_sigma=1 / 255, bits=8)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scale", type=int, default=1, help="sensor downscale factor (1 = 1024 x 768)")
    args = parser.parse_args()
    set_torch_threads(2)
    rig = thesis_setup1().downscaled(args.scale)
    scenes = [fronto_parallel_plane(rig, z, seed=i) for i, z in enumerate((312.0, 525.0, 780.0))]
    scenes.append(step_scene(rig, 450.0, 650.0, seed=12))
    images = render(rig, scenes, FORMATION).image
    print(f"thesis_setup1 {rig.image_width}x{rig.image_height}, 228-1374 mm, scenes: "
          f"{', '.join(s.name for s in scenes)}")
    with tempfile.TemporaryDirectory(prefix="onnx_parity_") as tmp:
        for options in ({}, {"downsample": 1}, {"downsample": 2, "full_band": 0},
                        {"downsample": 2, "full_band": 1, "band_edges": "clamp"}):
            model = PrismStereo(rig, (228.0, 1374.0), options).eval()
            runner = OnnxDepth(export_onnx(model, Path(tmp) / f"parity{len(options)}.onnx"))
            for batch in (1, 4):
                x = images[:batch]
                with torch.inference_mode():
                    want = model(x)
                got = runner(x)
                both = got.valid & want.valid
                rel = ((got.depth.double() - want.depth.double()).abs() / want.depth.double())[both]
                agree = 100 * float((got.valid == want.valid).double().mean())
                conf = float((got.confidence - want.confidence).abs().max())
                ok = float(rel.max()) <= 1e-4 and agree >= 99.9
                print(f"{str(options or 'defaults'):36s} batch {batch}: max rel {float(rel.max()):.2e}, 99.9th pct "
                      f"{float(rel.quantile(0.999)):.2e}, above 1e-4: {int((rel > 1e-4).sum())} of {rel.numel()}; "
                      f"valid flags agree {agree:.4f} %; max confidence difference {conf:.1e} -> "
                      f"{'targets met' if ok else 'TARGETS MISSED'}")


if __name__ == "__main__":
    main()
