"""One implementation per cost: the depth model's warped slices and column gathers (the rectified levels' and the
rectified-pair matcher's shift volume) are views compared by the same census / ZNCC / SAD; and the eager and
exported forms of :mod:`prismstereo.runtime` agree."""

import pytest
import torch

from prismstereo import OptionError, ShapeError
from prismstereo.matching import box_filter, census_transform
from prismstereo.matching.cost import Warped, ad_gradient_cost, reference_moments, sweep_cost, worst_cost, zncc_cost
from prismstereo.matching.sweep_cost import shift_cost, warp_slices
from prismstereo.runtime import crop, fill_invalid, scan_eager, scan_traced
from tests.matching.test_cost_select import disparity_volume, shifted_pair

F64 = torch.float64


def shifted_views(other, offsets, width):
    """Views of ``other`` (B, C, H, W_o) at columns u + offset (u < width), linearly interpolated, the edge columns
    replicated outside: (B, C, D, H, width), and their validity (1, D, 1, width): every tap inside."""
    w_o = other.shape[-1]
    views, valid = [], []
    for off in offsets.tolist():
        x = torch.arange(width) + off
        x0 = torch.floor(x)
        frac = (x - x0).to(other.dtype)
        left = other[..., x0.long().clamp(0, w_o - 1)]
        right = other[..., (x0.long() + 1).clamp(0, w_o - 1)]
        views.append((1 - frac) * left + frac * right)
        valid.append((x0 >= 0) & (x0 + (frac > 0).long() <= w_o - 1))
    return torch.stack(views, 2), torch.stack(valid).view(1, len(valid), 1, width)


def float_bit_census(reference, other, offsets, window, threshold=0.0):
    """Hamming distances of census_transform's bits of the reference and of each shifted view."""
    ref_bits = census_transform(reference, window, threshold)
    views, valid = shifted_views(other, offsets, reference.shape[-1])
    slices = []
    for k in range(views.shape[2]):
        hamming = (ref_bits - census_transform(views[:, :, k], window, threshold)).abs().sum(1)
        slices.append(torch.where(valid[0, k], hamming, torch.full_like(hamming, ref_bits.shape[1])))
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
    views, valid = shifted_views(other, offsets, 30)
    vol = sweep_cost(ref, Warped(views, valid), "census", window, threshold)
    d = len(offsets)
    assert vol.dtype == F64 and vol.shape == (2, d, 13, 30)
    torch.testing.assert_close(vol, float_bit_census(ref, other, offsets, window, threshold), rtol=0, atol=0)


def test_census_volume_finds_the_shift():
    left, right = shifted_pair(5.0, h=24, w=60, seed=5)
    vol = disparity_volume(left, right, 10, "census", 5, census_threshold=0.002)
    assert vol.dtype == F64
    assert (box_filter(vol, 5)[..., 10:-4].argmin(1) == 5).all()
    assert (vol[0, 9, :, :9] == worst_cost("census", 1, 5)).all()  # right column u - 9 outside for u < 9


@pytest.mark.parametrize("cost", ["sad", "zncc", "census"])
def test_column_shifts_warped_slices_and_gathers_give_one_cost(cost):
    """The same views built three ways (shifted columns, the model's plane-sweep warp and its column gather, which
    the rectified levels and the rectified-pair matcher use) get the same cost: one SAD / ZNCC (one variance floor) /
    census for all."""
    gen = torch.Generator().manual_seed(2)
    ref = torch.rand(1, 1, 16, 24, generator=gen, dtype=F64)
    other = torch.rand(1, 1, 16, 24, generator=gen, dtype=F64)
    shifts = [0, 1, 2, 3, 5]
    views, valid = shifted_views(other, torch.tensor(shifts, dtype=F64), 24)
    by_shift = sweep_cost(ref, Warped(views, valid), cost, 5, 0.01)
    v, u = torch.meshgrid(torch.arange(16, dtype=F64), torch.arange(24, dtype=F64), indexing="ij")
    grid = torch.stack([torch.stack([(2 * (u + s) + 1) / 24 - 1, (2 * v + 1) / 16 - 1], -1) for s in shifts])[None]
    warped = warp_slices(other, grid)
    by_warp = sweep_cost(ref, Warped(warped.image, valid), cost, 5, 0.01)
    torch.testing.assert_close(by_warp, by_shift, rtol=1e-12, atol=1e-12)
    index = (torch.arange(24) + torch.tensor(shifts).view(-1, 1)).clamp(max=23)
    by_gather = shift_cost(ref, other, index, valid.expand(1, -1, 16, -1), cost, 5, 0.01)
    torch.testing.assert_close(by_gather, by_shift, rtol=1e-12, atol=1e-12)


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
        disparity_volume(a, a, 2, "census", 5, -0.1)
    with pytest.raises(OptionError, match="census window must be >= 3"):
        census_transform(a, 1)
    with pytest.raises(OptionError, match="window must be an odd int >= 3"):
        disparity_volume(a, a, 2, "census", 4)
    with pytest.raises(ShapeError, match="disagree"):
        disparity_volume(a, torch.rand(1, 2, 8, 8), 2, "sad")
    with pytest.raises(ShapeError, match="image must have shape"):
        census_transform(torch.rand(8, 8))


def test_zncc_takes_the_reference_moments_it_would_compute():
    """ZNCC with the reference's moments given is ZNCC computing them, bitwise; moments of a constant image: its
    value minus 0.5 and no variance."""
    g = torch.Generator().manual_seed(7)
    ref, views = torch.rand(1, 1, 9, 11, generator=g), torch.rand(1, 1, 3, 9, 11, generator=g)
    assert torch.equal(zncc_cost(ref, views, 5, reference_moments(ref, 5)), zncc_cost(ref, views, 5))
    mean, var = reference_moments(torch.full((1, 3, 4, 4), 0.75), 3)
    assert mean.shape == (1, 1, 4, 4) and torch.allclose(mean, torch.full_like(mean, 0.25)) and var.abs().max() < 1e-7


def test_crop_slices_only_an_axis_that_is_longer():
    t = torch.arange(20.0).view(1, 1, 5, 4)
    assert crop(t, 5, 4) is t
    assert torch.equal(crop(t, 3, 4), t[..., :3, :]) and torch.equal(crop(t, 5, 2), t[..., :2])


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


def test_ad_gradient_is_one_cost_by_shifts_warps_and_gathers():
    """'ad_gradient' (Rhemann et al.'s truncated grey + gradient difference) of the same views built two ways:
    sweep_cost on shifted views (gradients of each view) and the model's column gather (gradients before the
    gather, the rectified levels' and the rectified-pair matcher's volume) agree wherever the view's gradient does
    not reach an edge of the image or of the view; the true shift costs 0."""
    gen = torch.Generator().manual_seed(6)
    other = torch.rand(1, 1, 16, 30, generator=gen, dtype=F64)
    ref = other[..., 3:27]  # reference column u shows other column u + 3
    shifts = [0, 1, 3, 4]
    views, valid = shifted_views(other[..., :24], torch.tensor(shifts, dtype=F64), 24)
    by_shift = sweep_cost(ref, Warped(views, valid), "ad_gradient")
    index = (torch.arange(24) + torch.tensor(shifts).view(-1, 1)).clamp(max=23)  # other column u + s
    gathered = shift_cost(ref, other[..., :24], index, valid.expand(1, -1, 16, -1), "ad_gradient")
    u = torch.arange(24).view(1, 1, 1, -1)
    s = torch.tensor(shifts).view(1, -1, 1, 1)
    interior = (valid & (u >= 1) & (u <= 22) & (u + s <= 22)).expand_as(by_shift)
    torch.testing.assert_close(gathered[interior], by_shift[interior], rtol=0, atol=1e-12)
    full = shift_cost(ref, other, (torch.arange(24) + torch.tensor(shifts).view(-1, 1)).clamp(max=29),
                      torch.ones(1, 4, 16, 24, dtype=torch.bool), "ad_gradient")
    # a batch is its images side by side (the gradients broadcast per image)
    pair = torch.cat([other, torch.rand(1, 1, 16, 30, generator=gen, dtype=F64)])
    refs = pair[..., 3:27]
    index_b = (torch.arange(24) + torch.tensor(shifts).view(-1, 1)).clamp(max=29)
    ones = torch.ones(1, 4, 16, 24, dtype=torch.bool)
    both = shift_cost(refs, pair, index_b, ones, "ad_gradient")
    for k in range(2):
        one = shift_cost(refs[k:k + 1], pair[k:k + 1], index_b, ones, "ad_gradient")
        torch.testing.assert_close(both[k:k + 1], one)
    views = Warped(pair[..., index_b].permute(0, 1, 3, 2, 4), ones)
    swept = sweep_cost(refs, views, "ad_gradient")
    for k in range(2):
        one = Warped(views.image[k:k + 1], ones)
        torch.testing.assert_close(swept[k:k + 1], sweep_cost(refs[k:k + 1], one, "ad_gradient"))
    # (the reference's edge columns have one-sided gradients where the other image's are central)
    assert float(full[:, 2, :, 1:-1].abs().max()) < 1e-12 and bool((full.argmin(1) == 2).float().mean() > 0.97)
    assert worst_cost("ad_gradient", 3, 5) == 1.0 and float(full.max()) <= 1.0


def test_ad_gradient_cost_reference_values_and_gradients():
    """((1 - a) min(AD, t_ad) + a min(GD, t_g)) / ((1 - a) t_ad + a t_g): 0 for equal views, 1 when both terms
    saturate, the weights in between; differentiable below the truncations."""
    assert float(ad_gradient_cost(torch.tensor(0.0), torch.tensor(0.0))) == 0.0
    assert float(ad_gradient_cost(torch.tensor(1.0), torch.tensor(1.0))) == pytest.approx(1.0)
    # only the colour term, half its truncation: (1 - a) t / 2 / ((1 - a) t + a t) = (1 - a) / 2 with equal t
    assert float(ad_gradient_cost(torch.tensor(0.05), torch.tensor(0.0), 0.1, 0.1, 0.3)) == pytest.approx(0.35)
    ad = torch.rand(5, generator=torch.Generator().manual_seed(7), dtype=F64).mul(0.02).requires_grad_(True)
    gd = torch.rand(5, generator=torch.Generator().manual_seed(8), dtype=F64).mul(0.005).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda a, g: ad_gradient_cost(a, g), (ad, gd))
