"""One implementation per cost: the rectified matcher's column shifts and the depth model's warped slices and
column gathers are views compared by the same census / ZNCC / SAD; and the eager and exported forms of
:mod:`prismstereo._graph` agree."""

import pytest
import torch

from prismstereo import OptionError, ShapeError
from prismstereo._graph import fill_invalid, scan_eager, scan_traced
from prismstereo.matching import box_filter, census_transform, cost_volume, shifted
from prismstereo.matching.cost import Warped, sweep_cost
from prismstereo.matching.sweep_cost import shift_cost, warp_slices
from tests.matching.test_cost_select import shifted_pair

F64 = torch.float64


def float_bit_census(reference, other, offsets, window, threshold=0.0):
    """Hamming distances of census_transform's bits of the reference and of each shifted view."""
    ref_bits = census_transform(reference, window, threshold)
    slices = []
    for off in offsets.tolist():
        view, ok = shifted(other, off, reference.shape[-1])
        hamming = (ref_bits - census_transform(view, window, threshold)).abs().sum(1)
        slices.append(torch.where(ok, hamming, torch.full_like(hamming, ref_bits.shape[1])))
    return torch.stack(slices, 1)


def test_census_threshold_ignores_small_differences():
    img = torch.tensor([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [7.0, 8.0, 9.0]]).view(1, 1, 3, 3)
    assert int(census_transform(img, 3)[0, :, 1, 1].sum()) == 4  # 1, 2, 3, 4 are darker than 5
    assert int(census_transform(img, 3, threshold=1.5)[0, :, 1, 1].sum()) == 3  # 4 is within 1.5 of 5
    flat = 0.5 + 0.001 * torch.randn(1, 1, 16, 16, generator=torch.Generator().manual_seed(1))
    assert int(census_transform(flat, 5, threshold=0.01).max()) == 0  # noise below the threshold


@pytest.mark.parametrize("channels,window,threshold", [(1, 5, 0.0), (3, 3, 0.0), (1, 7, 0.01)])
@pytest.mark.parametrize("step", [1.0, 0.5])
def test_census_volume_is_the_hamming_distance_of_the_views_bits(channels, window, threshold, step):
    gen = torch.Generator().manual_seed(channels + window)
    ref = torch.rand(2, channels, 13, 30, generator=gen, dtype=F64)
    other = torch.rand(2, channels, 13, 26, generator=gen, dtype=F64)  # another width
    offsets = torch.arange(-6.0, 3.0, step, dtype=F64)
    vol = cost_volume(ref, other, offsets, "census", window, threshold)
    d = len(offsets)
    assert vol.cost.dtype == F64 and vol.cost.shape == (2, d, 13, 30) and vol.valid.shape == (1, d, 1, 30)
    torch.testing.assert_close(vol.cost, float_bit_census(ref, other, offsets, window, threshold), rtol=0, atol=0)


def test_census_volume_finds_the_shift():
    left, right = shifted_pair(5.0, h=24, w=60, seed=5)
    vol = cost_volume(left, right, -torch.arange(10.0, dtype=F64), "census", 5, census_threshold=0.002)
    assert vol.cost.dtype == F64
    assert (box_filter(vol.cost, 5)[..., 10:-4].argmin(1) == 5).all()
    assert not vol.valid[0, 9, 0, :9].any() and vol.valid[0, 9, 0, 9:].all()


@pytest.mark.parametrize("cost", ["sad", "zncc", "census"])
def test_column_shifts_warped_slices_and_gathers_give_one_cost(cost):
    """The same views built three ways (the rectified matcher's shifts, the model's plane-sweep warp and its
    column gather) get the same cost: one SAD / ZNCC (one variance floor) / census for both."""
    gen = torch.Generator().manual_seed(2)
    ref = torch.rand(1, 1, 16, 24, generator=gen, dtype=F64)
    other = torch.rand(1, 1, 16, 24, generator=gen, dtype=F64)
    shifts = [0, 1, 2, 3, 5]
    by_shift = cost_volume(ref, other, torch.tensor(shifts, dtype=F64), cost, 5, 0.01)
    v, u = torch.meshgrid(torch.arange(16, dtype=F64), torch.arange(24, dtype=F64), indexing="ij")
    grid = torch.stack([torch.stack([(2 * (u + s) + 1) / 24 - 1, (2 * v + 1) / 16 - 1], -1) for s in shifts])[None]
    warped = warp_slices(other, grid)
    by_warp = sweep_cost(ref, Warped(warped.image, by_shift.valid), cost, 5, 0.01)
    torch.testing.assert_close(by_warp, by_shift.cost, rtol=1e-12, atol=1e-12)
    index = (torch.arange(24) + torch.tensor(shifts).view(-1, 1)).clamp(max=23)
    by_gather = shift_cost(ref, other, index, by_shift.valid.expand(1, -1, 16, -1), cost, 5, 0.01)
    torch.testing.assert_close(by_gather, by_shift.cost, rtol=1e-12, atol=1e-12)


def test_zncc_has_the_variance_floor():
    """A flat view is uncorrelated (cost 1), not a ratio of rounding errors."""
    ref = torch.rand(1, 1, 9, 9, generator=torch.Generator().manual_seed(4), dtype=F64)
    vol = sweep_cost(ref, Warped(torch.full((1, 1, 1, 9, 9), 0.3, dtype=F64), torch.ones(1, 1, 9, 9, dtype=torch.bool)),
                     "zncc", 3)
    torch.testing.assert_close(vol, torch.ones_like(vol))


def test_cost_volume_errors():
    a = torch.rand(1, 1, 8, 8)
    with pytest.raises(OptionError, match="census threshold must be >= 0"):
        census_transform(a, 5, threshold=-0.1)
    with pytest.raises(OptionError, match="census_threshold must be >= 0"):
        cost_volume(a, a, torch.zeros(2), "census", 5, -0.1)
    with pytest.raises(OptionError, match="census window must be >= 3"):
        census_transform(a, 1)
    with pytest.raises(OptionError, match="window must be a positive odd int"):
        cost_volume(a, a, torch.zeros(2), "census", 4)
    with pytest.raises(ShapeError, match="must share B, C, H"):
        cost_volume(a, torch.rand(1, 2, 8, 8), torch.zeros(2))
    with pytest.raises(ShapeError, match="image must have shape"):
        census_transform(torch.rand(8, 8))


def _export_forms(monkeypatch):
    monkeypatch.setattr(torch.onnx, "is_in_onnx_export", lambda: True)


@pytest.mark.parametrize("bounded", [False, True])
def test_fill_forms_agree(bounded, monkeypatch):
    volume = torch.rand(2, 3, 4, 5, generator=torch.Generator().manual_seed(0))
    valid = torch.rand(1, 3, 1, 5, generator=torch.Generator().manual_seed(1)) > 0.5
    eager = fill_invalid(volume, valid, 1.0, bounded)
    _export_forms(monkeypatch)
    assert torch.equal(fill_invalid(volume, valid, 1.0, bounded), eager)


@pytest.mark.parametrize("shift", [0, 1])
@pytest.mark.parametrize("penalties", [False, True])
def test_eager_and_exported_sgm_scans_agree_bitwise(shift, penalties, monkeypatch):
    gen = torch.Generator().manual_seed(shift)
    volume = -torch.rand(7, 2, 6, 5, generator=gen)
    p2s = 0.5 + torch.rand(7, 2, 1, 5, generator=gen) if penalties else None
    eager = scan_eager(volume, 0.1, 0.6, shift, p2s)
    assert torch.equal(scan_traced(volume, 0.1, 0.6, shift, p2s), eager)  # the Concat / Maximum form
    _export_forms(monkeypatch)
    assert torch.equal(scan_traced(volume, 0.1, 0.6, shift, p2s), eager)  # with the MaxPool of an export
