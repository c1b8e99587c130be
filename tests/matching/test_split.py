import pytest
import torch

from prismstereo import ShapeError, thesis_setup1
from prismstereo.matching import SplitImage


def test_split_at_apex_column():
    rig = thesis_setup1()
    img = torch.arange(1024.0).view(1, 1, 1, 1024).expand(2, 3, 768, 1024)
    halves = SplitImage(rig)(img)
    assert halves.reference.shape == (2, 3, 768, 512) and halves.other.shape == (2, 3, 768, 512)
    assert halves.reference[0, 0, 0, -1] == 511 and halves.other[0, 0, 0, 0] == 512


def test_split_moves_with_prism_offset():
    rig = thesis_setup1().replace(prism_offset_x_mm=2.0)  # apex column 511.5 + 63.3 = 574.8
    halves = SplitImage(rig)(torch.zeros(1, 1, 768, 1024))
    assert halves.reference.shape[-1] == 575 == rig.reference_width
    assert halves.other.shape[-1] == 1024 - 575


def test_split_rejects_wrong_size():
    split = SplitImage(thesis_setup1())
    with pytest.raises(ShapeError, match="image is 640x480 px but the rig's sensor is 1024x768"):
        split(torch.zeros(1, 1, 480, 640))
    with pytest.raises(ShapeError, match=r"image must have shape \(B, C, H, W\)"):
        split(torch.zeros(768, 1024))
