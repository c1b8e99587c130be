import pytest
import torch

from prismstereo import OptionError, ShapeError
from prismstereo.matching import box_filter, census_codes, census_transform, census_volume, cost_volume, shifted
from tests.matching.test_cost_select import shifted_pair

F64 = torch.float64


def popcount(codes: torch.Tensor) -> torch.Tensor:
    table = torch.tensor([bin(i).count("1") for i in range(256)])
    return table[codes.long()].sum(1)


def float_bit_census(reference, other, offsets, window):
    """The census volume from one float channel per bit (cost_volume's path for fractional offsets)."""
    ref_bits, other_bits = census_transform(reference, window), census_transform(other, window)
    slices = []
    for off in offsets.tolist():
        view, ok = shifted(other_bits, off, reference.shape[-1])
        slices.append(torch.where(ok, (ref_bits - view).abs().sum(1), torch.full_like(view[:, 0], ref_bits.shape[1])))
    return torch.stack(slices, 1)


def test_census_codes_pack_the_census_bits():
    gen = torch.Generator().manual_seed(0)
    img = torch.rand(2, 3, 9, 11, generator=gen, dtype=F64)
    codes = census_codes(img, 5)
    assert codes.dtype == torch.uint8 and codes.shape == (2, 9, 9, 11)  # 3 * 24 bits = 9 bytes
    torch.testing.assert_close(popcount(codes), census_transform(img, 5).sum(1).long())


def test_census_threshold_ignores_small_differences():
    img = torch.tensor([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [7.0, 8.0, 9.0]]).view(1, 1, 3, 3)
    assert int(popcount(census_codes(img, 3))[0, 1, 1]) == 4  # 1, 2, 3, 4 are darker than 5
    assert int(popcount(census_codes(img, 3, threshold=1.5))[0, 1, 1]) == 3  # 4 is within 1.5 of 5
    flat = 0.5 + 0.001 * torch.randn(1, 1, 16, 16, generator=torch.Generator().manual_seed(1))
    assert int(popcount(census_codes(flat, 5, threshold=0.01)).max()) == 0  # noise below the threshold


@pytest.mark.parametrize("channels,window", [(1, 5), (3, 3), (1, 7)])
def test_census_volume_matches_the_float_bit_volume(channels, window):
    gen = torch.Generator().manual_seed(channels + window)
    ref = torch.rand(2, channels, 13, 30, generator=gen, dtype=F64)
    other = torch.rand(2, channels, 13, 26, generator=gen, dtype=F64)  # another width
    offsets = torch.arange(-6.0, 3.0, dtype=F64)
    vol = census_volume(ref, other, offsets, window)
    assert vol.cost.dtype == F64 and vol.cost.shape == (2, 9, 13, 30) and vol.valid.shape == (1, 9, 1, 30)
    torch.testing.assert_close(vol.cost, float_bit_census(ref, other, offsets, window))
    # cost_volume takes this path for integer offsets: same values and mask
    via = cost_volume(ref, other, offsets, "census", window)
    torch.testing.assert_close(via.cost, vol.cost)
    assert torch.equal(via.valid, vol.valid)


def test_census_volume_finds_the_shift():
    left, right = shifted_pair(5.0, h=24, w=60, seed=5)
    vol = census_volume(left, right, -torch.arange(10), 5, threshold=0.002)
    assert vol.cost.dtype == F64
    assert (box_filter(vol.cost, 5)[..., 10:-4].argmin(1) == 5).all()
    assert not vol.valid[0, 9, 0, :9].any() and vol.valid[0, 9, 0, 9:].all()


def test_census_errors():
    a = torch.rand(1, 1, 8, 8)
    with pytest.raises(OptionError, match="needs integer offsets"):
        census_volume(a, a, torch.tensor([0.0, -1.5]))
    with pytest.raises(OptionError, match="census threshold must be >= 0"):
        census_codes(a, 5, threshold=-0.1)
    with pytest.raises(OptionError, match="census window must be >= 3"):
        census_codes(a, 1)
    with pytest.raises(OptionError, match="window must be a positive odd int"):
        census_volume(a, a, torch.zeros(2), 4)
    with pytest.raises(ShapeError, match="must share B, C, H"):
        census_volume(a, torch.rand(1, 2, 8, 8), torch.zeros(2))
    with pytest.raises(ShapeError, match="image must have shape"):
        census_codes(torch.rand(8, 8))
