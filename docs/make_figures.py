"""Regenerate the README's picture (docs/images/overview.png): a capture through the prism, its depth map and
the point cloud, all from the library (run: .venv/bin/python docs/make_figures.py)."""

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import torch  # noqa: E402

from prismstereo import PrismStereo, thesis_setup1  # noqa: E402
from prismstereo.depth import depth_to_points  # noqa: E402
from prismstereo.synthetic import ImageFormation, render, sphere_scene  # noqa: E402
from prismstereo.threads import set_torch_threads  # noqa: E402


def main() -> None:
    set_torch_threads(2)
    rig = thesis_setup1()
    capture = render(rig, sphere_scene(rig, 560.0, 14.0, 700.0, seed=3), ImageFormation(supersample=2,
                                                                                          noise_sigma=1 / 255))
    model = PrismStereo(rig, (400.0, 900.0)).eval()
    with torch.inference_mode():
        result = model(capture.image)
        points = depth_to_points(rig, result.depth.double(), result.valid)[0]
    w = rig.reference_width
    fig = plt.figure(figsize=(15, 4.2))
    ax = fig.add_subplot(1, 3, 1)
    ax.imshow(capture.image[0, 0], cmap="gray")
    ax.axvline(w - 0.5, color="r", lw=0.8)
    ax.set_title("one capture: the two half-images (red: the apex line)")
    ax.axis("off")
    ax = fig.add_subplot(1, 3, 2)
    depth = torch.where(result.valid, result.depth, torch.tensor(float("nan")))[0, 0]
    im = ax.imshow(depth, cmap="turbo_r", vmin=540, vmax=705)
    ax.set_title("depth of the reference (left) half, mm")
    ax.axis("off")
    fig.colorbar(im, ax=ax, fraction=0.04)
    ax = fig.add_subplot(1, 3, 3, projection="3d")
    xyz = points.permute(1, 2, 0)[result.valid[0, 0]][::25].numpy()
    ax.scatter(xyz[:, 0], xyz[:, 2], -xyz[:, 1], c=xyz[:, 2], cmap="turbo_r", s=0.5, vmin=540, vmax=705)
    ax.set_xlabel("x (mm)")
    ax.set_ylabel("z (mm)")
    ax.set_zlabel("-y (mm)")
    ax.view_init(elev=20, azim=-60)
    ax.set_title("point cloud (exact ray tracing)")
    fig.tight_layout()
    out = Path(__file__).resolve().parent / "images" / "overview.png"
    fig.savefig(out, dpi=80)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
