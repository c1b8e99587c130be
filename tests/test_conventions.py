"""The conventions' one function: the grey rule (:func:`prismstereo.conventions.to_grey`)."""

import pytest
import torch
from kornia.color import rgb_to_grayscale

from prismstereo.conventions import to_grey
from prismstereo.errors import ShapeError


def test_to_grey_is_the_bt601_luma_of_rgb_and_keeps_grey():
    gen = torch.Generator().manual_seed(0)
    rgb = torch.rand(2, 3, 4, 5, generator=gen, dtype=torch.float64)
    grey = to_grey(rgb)
    assert grey.shape == (2, 1, 4, 5) and grey.dtype == torch.float64
    torch.testing.assert_close(grey, 0.299 * rgb[:, :1] + 0.587 * rgb[:, 1:2] + 0.114 * rgb[:, 2:])
    for dtype in (torch.float64, torch.float32, torch.float16, torch.bfloat16):  # the same bits as kornia's
        assert torch.equal(to_grey(rgb.to(dtype)), rgb_to_grayscale(rgb.to(dtype)))
        assert torch.equal(to_grey(rgb[0].to(dtype)), rgb_to_grayscale(rgb[0].to(dtype)))  # (C, H, W) too
    one = rgb[:, :1]
    assert to_grey(one) is one
    with pytest.raises(ShapeError, match="1 \\(grey\\) or 3 \\(RGB\\) channels, got 2"):
        to_grey(rgb[:, :2])
    with pytest.raises(TypeError, match="floating-point"):
        to_grey(torch.zeros(3, 4, 5, dtype=torch.uint8))
    volume = torch.rand(2, 3, 4, 5, 6, generator=gen)  # channels on another axis: the matching stages' volumes
    torch.testing.assert_close(to_grey(volume, dim=1)[:, :, 1], to_grey(volume[:, :, 1]))
