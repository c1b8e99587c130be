"""RectifiedCostVolume: group-wise correlation by column shifts on row-rectified feature maps."""

import pytest
import torch

from prismstereo import thesis_setup1, thesis_setup2
from prismstereo.epipolar.sweep_table import cubic_at, local_cubic
from prismstereo.errors import OptionError, ShapeError
from prismstereo.nn.rectified_volume import RectifiedCostVolume
from prismstereo.runtime import sample_grid

pytestmark = pytest.mark.usefixtures("one_thread")

Z = (450.0, 1000.0)


@pytest.fixture(scope="module", params=["setup1", "setup2", "offset split"])
def volume(request):
    rig = {"setup1": thesis_setup1, "setup2": thesis_setup2}.get(request.param, thesis_setup1)().downscaled(2)
    if request.param == "offset split":  # the split between feature columns
        rig = rig.replace(prism_offset_x_mm=0.2)
        assert rig.reference_width % 8
    return RectifiedCostVolume(rig, Z, 8, groups=2)


def test_entries_correlate_the_shifted_rectified_columns(volume):
    features = torch.randn(2, 4, volume.height, volume.width, generator=torch.Generator().manual_seed(0))
    cost = volume(features)
    d, w_l, h_r = volume.valid.shape
    assert cost.shape == (2, 2, d, w_l, h_r)
    reference = volume.rectified_reference(features)  # (B, C, W_l, H_r)
    grid = volume.other_grid.unsqueeze(0).expand(2, -1, -1, -1)
    other = sample_grid(features, grid).transpose(-1, -2)  # (B, C, W_ol, H_r)
    i, u, r = (int(x) for x in volume.valid.nonzero()[volume.valid.sum() // 2])
    column = u + int(volume.shifts[i])
    expected = (reference[:, :, u, r] * other[:, :, column, r]).view(2, 2, 2).mean(-1)
    assert torch.allclose(cost[:, :, i, u, r], expected, atol=1e-6)
    assert (cost[:, :, ~volume.valid] == 0).all()


def test_a_shift_compares_the_exact_correspondence(volume):
    """Shift k of a rectified reference pixel samples the other half where its exact sweep passes at the s that
    to_sweep gives k (the column by construction, the row within the rectification's residual)."""
    d, w_l, h_r = volume.valid.shape
    shifts = volume.shifts.view(1, -1, 1, 1).expand(1, d, w_l, h_r)  # transposed, as the volume
    s = torch.cat([volume.to_sweep(shifts[:, i:i + 1]) for i in range(d)], 1)  # (1, D, H_r, W_l)
    valid = volume.valid.transpose(-1, -2).unsqueeze(0)  # (1, D, H_r, W_l)
    f = volume.scale
    rows, columns = [], []
    for i in range(d):
        cubic = local_cubic(volume.table, s[:, i:i + 1])
        match = cubic_at(cubic, cubic.u)  # (1, 1, H_r, W_l, 2) full-sensor position of the exact match
        rows.append(match[..., 1])
        columns.append(match[..., 0])
    exact_row = torch.cat(rows, 1)
    # the row and column the rectified other pixel u + k reads (other_grid, on the whole feature map), full-sensor
    y = (volume.other_grid[..., 1] + 1.0) * f * volume.height / 2 - 0.5  # (H_r, W_ol)
    x = (volume.other_grid[..., 0] + 1.0) * f * volume.width / 2 - 0.5
    column = (torch.arange(w_l).view(1, 1, -1) + volume.shifts.view(-1, 1, 1).long()).clamp(0, y.shape[1] - 1)
    read_row, read_column = (t.unsqueeze(0).expand(d, -1, -1).gather(2, column.expand(-1, y.shape[0], -1)
                                                                        ).unsqueeze(0) for t in (y, x))
    exact_column = torch.cat(columns, 1)
    inside = valid & (s.abs() < 0.999)
    assert inside.sum() > 1000
    assert (exact_row - read_row)[inside].abs().max() < 0.25  # full-resolution px (setup 2's warp residual)
    assert (exact_column - read_column)[inside].abs().max() < 1e-3


def test_truth_shift_and_to_sweep_are_inverse(volume):
    s = torch.full((1, 1, volume.height, volume.reference_width), 0.25)
    known = torch.ones_like(s, dtype=torch.bool)
    index, known_r = volume.truth_shift(s, known)
    back = volume.to_sweep(index + volume.shifts[0])
    assert known_r.float().mean() > 0.9
    assert (back - 0.25).abs()[known_r.transpose(-1, -2)].max() < 1e-4
    # unknown truths stay unknown around them
    known[..., 10, 10] = False
    assert volume.truth_shift(s, known)[1].sum() < known_r.sum()


def test_errors():
    with pytest.raises(OptionError, match="multiples of 8"):
        RectifiedCostVolume(thesis_setup1().downscaled(4).replace(image_width=252), Z, 8)
    volume = RectifiedCostVolume(thesis_setup1().downscaled(4), Z, 8, groups=2)
    with pytest.raises(ShapeError, match="multiple of 2"):
        volume(torch.rand(1, 3, volume.height, volume.width))
    with pytest.raises(ShapeError, match=r"\(B, C, 24, 32\)"):
        volume(torch.rand(1, 4, 24, 30))
