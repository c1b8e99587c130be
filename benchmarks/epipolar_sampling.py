"""Exact plane-sweep sampling vs the shift-band fast form: residual against the exact grid and cost.

For thesis setups 1 and 2 over the thesis' working range 228-1374 mm with hypotheses about 1 px apart
(368 and 456), it prints the fast form's residual (px) per band count, measured against the exact grid
on every 48th image row, and the time to sample a 768 x 512 right half for all hypotheses in torch
(one batched grid_sample of D grids vs one grid_sample per band plus D fractional column shifts).

Run: .venv/bin/python benchmarks/epipolar_sampling.py
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from _timing import median_ms  # benchmarks/_timing.py (scripts run from this folder)

from prismstereo import thesis_setup1, thesis_setup2
from prismstereo.epipolar import band_residual, depth_hypotheses, exact_sampling_grid, shift_bands
from prismstereo.threads import set_torch_threads


def _sampling_cost(h: int, w_ref: int, d: int, bands: int) -> tuple[float, float]:
    gen = torch.Generator().manual_seed(0)
    img = torch.rand(1, 1, h, w_ref, generator=gen)
    grids = torch.rand(d, h, w_ref, 2, generator=gen) * 2 - 1
    per_hyp = median_ms(lambda: F.grid_sample(img.expand(d, -1, -1, -1), grids, align_corners=False), 3)
    wx = w_ref + d // bands + 4
    band_grids = torch.rand(bands, h, wx, 2, generator=gen) * 2 - 1
    shifts = torch.linspace(0, d // bands, d)

    def banded() -> torch.Tensor:
        warped = F.grid_sample(img.expand(bands, -1, -1, -1), band_grids, align_corners=False)
        out = torch.empty(d, h, w_ref)
        for i in range(d):
            s = float(shifts[i])
            k, a = int(s), s - int(s)
            src = warped[i * bands // d, 0]
            out[i] = (1 - a) * src[:, k:k + w_ref] + a * src[:, k + 1:k + 1 + w_ref]
        return out

    return per_hyp, median_ms(banded, 3)


def main() -> None:
    set_torch_threads(2)
    rows = torch.arange(0, 768, 48)
    for name, rig, d in (("thesis_setup1", thesis_setup1(), 368), ("thesis_setup2", thesis_setup2(), 456)):
        depths = depth_hypotheses(228.0, 1374.0, d)
        exact = exact_sampling_grid(rig, depths, rows=rows)
        step = (exact.uv[1:] - exact.uv[:-1]).norm(dim=-1)[exact.valid[1:] & exact.valid[:-1]].max()
        print(f"{name}: D={d} hypotheses 228-1374 mm, largest step between neighbours {step:.2f} px")
        header = ("bands", "max px", "horiz", "vert", "mean px", "grid_sample ms", "bands ms")
        print("  " + " ".join(f"{h:>{w}s}" for h, w in zip(header, (5, 8, 7, 7, 8, 15, 9), strict=True)))
        for bands in (1, 8, 32, 64, 128, 256):
            res = band_residual(exact, shift_bands(rig, depths, bands, rows=rows, exact=exact))
            per_hyp, banded = _sampling_cost(rig.image_height, rig.reference_width, d, bands)
            print(f"  {bands:5d} {res.max_px:8.3f} {res.max_horizontal_px:7.3f} {res.max_vertical_px:7.3f} "
                  f"{res.mean_px:8.4f} {per_hyp:15.0f} {banded:9.0f}")


if __name__ == "__main__":
    main()
