"""Depth previews (prismstereo.preview)."""

import matplotlib
import pytest
import torch

from prismstereo.io import ImageIOError, read_image
from prismstereo.preview import INVALID_GREY, depth_preview, write_depth_preview


def test_depth_preview(tmp_path):
    """Depths as colours of inverse depth, pixels without one hatched in grey (no colormap colour), and a colour
    bar on the right from near (top) to far (bottom) labelled in mm."""
    depth = torch.linspace(300.0, 900.0, 96 * 64).reshape(96, 64)
    depth[0, 0] = float("nan")
    valid = torch.ones(96, 64, dtype=torch.bool)
    valid[40:60, 20:40] = False
    write_depth_preview(tmp_path / "p.png", depth, valid)
    img = read_image(tmp_path / "p.png")
    assert img.shape[:2] == (3, 96) and img.shape[2] > 64  # the bar beside the map
    grey = {round(g / 255, 3) for g in INVALID_GREY}
    hatched = img[:, 40:60, 20:40]
    assert (hatched[0] == hatched[1]).all() and (hatched[1] == hatched[2]).all()  # grey
    assert {round(float(v), 3) for v in hatched[0].unique()} == grey  # both stripes
    assert round(float(img[0, 0, 0]), 3) in grey
    colours = torch.tensor(matplotlib.colormaps["turbo"](torch.linspace(0, 1, 256).numpy())[:, :3])
    assert float(torch.cdist(hatched[:, 0, :2].T.double(), colours.double()).min()) > 0.05  # unlike any map colour
    assert (img[:, 10, 1] - img[:, 90, 1]).abs().sum() > 0.5  # near and far get different colours
    bar = read_image(tmp_path / "p.png")[:, :, 64:]
    column = bar[:, :, 6:10].mean(-1)  # the colour strip: near (top) warm, far (bottom) cool, as the map
    assert column[0, 0] > column[2, 0] and column[2, -1] > column[0, -1]
    assert float((bar[:, :, 20:] < 0.5).float().mean()) > 0.01  # dark label text on the white background
    plain = depth_preview(depth, valid, colorbar=False, limits_mm=(300.0, 900.0))
    assert plain.shape == (96, 64, 3)
    with pytest.raises(ImageIOError, match="unknown matplotlib colormap"):
        write_depth_preview(tmp_path / "p.png", depth, cmap="nope")
