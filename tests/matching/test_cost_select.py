import pytest
import torch

from prismstereo import OptionError, ShapeError
from prismstereo.matching import (
    box_filter,
    census_transform,
    left_right_check,
    shift_cost,
    soft_argmin_local,
    subpixel_refine,
    uniqueness,
    winner_take_all,
)
from prismstereo.synthetic import NoiseTexture

F64 = torch.float64


def textured(h=40, w=120, seed=0, channels=1, feature=1.5):
    """A smooth random image sampled on a fine grid (so sub-pixel shifts are well defined)."""
    tex = NoiseTexture(feature, seed=seed, channels=channels)
    v, u = torch.meshgrid(torch.arange(h, dtype=F64), torch.arange(w + 40, dtype=F64), indexing="ij")
    return tex, v, u


def shifted_pair(disparity: float, h=40, w=120, seed=0, channels=1):
    """Left image and a right image with constant disparity: right(u) = left(u + d)."""
    tex, v, u = textured(h, w, seed, channels)
    left = tex.sample(torch.stack([u[:, :w], v[:, :w]], -1).reshape(-1, 2)).T.reshape(channels, h, w)
    right = tex.sample(torch.stack([u[:, :w] + disparity, v[:, :w]], -1).reshape(-1, 2)).T.reshape(channels, h, w)
    return left[None], right[None]


def disparity_volume(left, right, num, cost, window=5, census_threshold=0.0):
    """The shift volume of a rectified pair (:func:`shift_cost`): hypothesis d compares left column u with right
    column u - d (real where u - d >= 0, worst cost elsewhere), (B, num, H, W)."""
    h, w = left.shape[-2:]
    column = torch.arange(w) - torch.arange(num).view(-1, 1)
    valid = (column >= 0).view(1, num, 1, w).expand(1, num, h, w)
    return shift_cost(left, right, column.clamp_min(0), valid, cost, window, census_threshold)


def test_box_filter_is_a_mean():
    vol = torch.rand(2, 3, 9, 11)
    out = box_filter(vol, 3)
    torch.testing.assert_close(out[..., 4, 5], vol[..., 3:6, 4:7].mean((-1, -2)))
    torch.testing.assert_close(out[..., 0, 0], vol[..., :2, :2].mean((-1, -2)))  # borders: inside pixels only
    with pytest.raises(OptionError, match="positive odd int"):
        box_filter(vol, 4)


@pytest.mark.parametrize("size", [(1, 1), (2, 3), (3, 2), (6, 17), (13, 9)])
@pytest.mark.parametrize("window", [3, 7])
def test_box_filter_matches_avg_pool_and_its_export_form(size, window):
    """The eager in-place shifted sums equal avg_pool2d without the padding (the exported form), also on
    volumes smaller than the window; float64 gradcheck."""
    vol = torch.rand(2, 3, *size, dtype=F64, generator=torch.Generator().manual_seed(3))
    reference = torch.nn.functional.avg_pool2d(vol, window, stride=1, padding=window // 2, count_include_pad=False)
    torch.testing.assert_close(box_filter(vol, window), reference, rtol=1e-12, atol=1e-12)
    assert box_filter(vol, 1) is vol
    torch.autograd.gradcheck(lambda v: box_filter(v, window), (vol[:1, :2].clone().requires_grad_(),))


def test_census_bits():
    img = torch.tensor([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [7.0, 8.0, 9.0]]).view(1, 1, 3, 3)
    bits = census_transform(img, 3)
    assert bits.shape == (1, 8, 3, 3)
    assert bits[0, :, 1, 1].tolist() == [1, 1, 1, 1, 0, 0, 0, 0]  # neighbours darker than the centre 5
    with pytest.raises(OptionError, match="census window must be >= 3"):
        census_transform(img, 1)


@pytest.mark.parametrize("cost,method", [("sad", "equiangular"), ("census", "equiangular"), ("zncc", "parabola")])
@pytest.mark.parametrize("disparity", [7.0, 12.3, 20.75])
def test_constant_shift_recovered_to_0_05_px(cost, method, disparity):
    left, right = shifted_pair(disparity)
    window = 9 if cost == "zncc" else 5  # ZNCC's normalisation is noisy on small windows (0.1 px at 5x5)
    vol = disparity_volume(left, right, 32, cost, window)  # hypothesis k: right column u - k
    agg = box_filter(vol, 5) if cost != "zncc" else vol
    index, _ = winner_take_all(agg)
    refined = subpixel_refine(agg, index, method)
    inner = refined[..., 8:-8, 40:-8]  # away from borders and the invalid left columns
    assert (inner - disparity).abs().median() < 0.05
    assert (inner - disparity).abs().quantile(0.9) < 0.15


def test_parabola_on_sad_pixel_locks():
    # the measured fact: a parabola fitted to an L1 cost is biased toward integers, the V fit is not
    left, right = shifted_pair(12.3)
    agg = box_filter(disparity_volume(left, right, 32, "sad"), 7)
    index, _ = winner_take_all(agg)
    bias_parabola = (subpixel_refine(agg, index, "parabola")[..., 8:-8, 40:-8] - 12.3).median()
    bias_v = (subpixel_refine(agg, index, "equiangular")[..., 8:-8, 40:-8] - 12.3).median()
    assert bias_parabola < -0.05 and abs(bias_v) < 0.02


def test_rgb_costs_and_shapes():
    left, right = shifted_pair(5.0, channels=3)
    vol = disparity_volume(left, right, 10, "census", 3)
    assert vol.shape == (1, 10, 40, 120) and vol.dtype == F64
    assert vol.max() <= 3 * 8 and (vol[0, 9, :, :9] == 3 * 8).all()  # a colour census: 8 bits per channel
    assert (box_filter(vol, 5)[..., 12:-4].argmin(1) == 5).float().mean() > 0.95


def test_cost_errors():
    a = torch.rand(1, 1, 8, 8)
    with pytest.raises(OptionError, match="Unknown cost 'ssd'. Choose from: 'sad', 'zncc', 'census'"):
        disparity_volume(a, a, 2, "ssd")
    with pytest.raises(ShapeError, match="disagree"):
        disparity_volume(a, torch.rand(1, 1, 9, 8), 2, "sad")
    with pytest.raises(OptionError, match="window must be a positive odd int"):
        disparity_volume(a, a, 2, "zncc", window=2)


def test_subpixel_fits_exact_models():
    # V-shaped cost (L1): equiangular is exact; parabolic cost: parabola is exact
    x = torch.arange(10, dtype=F64).view(1, 10, 1, 1)
    for true in (3.2, 6.45, 4.0):
        v_cost = (x - true).abs()
        idx, _ = winner_take_all(v_cost)
        assert float(subpixel_refine(v_cost, idx, "equiangular")) == pytest.approx(true)
        p_cost = (x - true) ** 2
        idx, _ = winner_take_all(p_cost)
        assert float(subpixel_refine(p_cost, idx, "parabola")) == pytest.approx(true)
    # a parabola on a V cost pixel-locks (biased toward the integer)
    v_cost = (x - 3.25).abs()
    assert abs(float(subpixel_refine(v_cost, winner_take_all(v_cost)[0], "parabola")) - 3.25) > 0.05
    with pytest.raises(OptionError, match="Unknown method 'cubic'"):
        subpixel_refine(v_cost, winner_take_all(v_cost)[0], "cubic")


@pytest.mark.parametrize("index", [4, "tensor"])
def test_subpixel_limit_lets_a_fit_reach_the_outer_sample(index):
    """Around a hypothesis one step from a parabolic cost's minimum the fit finds the minimum with limit 1 (what a
    clamped band on a prior one step behind uses); the default half step stops half way."""
    x = torch.arange(10, dtype=F64).view(1, 10, 1, 1)
    cost = (x - 4.8) ** 2  # the winner would be 5: refine around 4 instead
    j = 4 if index == 4 else torch.full((1, 1, 1, 1), 4, dtype=torch.long)
    assert float(subpixel_refine(cost, j, "parabola", limit=1.0)) == pytest.approx(4.8)
    assert float(subpixel_refine(cost, j, "parabola")) == pytest.approx(4.5)
    assert float(subpixel_refine((x - 5.7) ** 2, j, "parabola", limit=1.0)) == pytest.approx(5.0)  # beyond: the edge
    for bad in (0.0, 1.5, True):
        with pytest.raises(OptionError, match=r"limit must be a number in \(0, 1\]"):
            subpixel_refine(cost, j, "parabola", limit=bad)


@pytest.mark.parametrize("method", ["parabola", "equiangular"])
def test_subpixel_refine_with_one_winner_for_all_pixels(method):
    """An int winner (static slices) gives bitwise the numbers of the same winner as an index tensor,
    including the ends (no refinement there), and is checked against the hypothesis count."""
    cost = torch.rand(2, 5, 6, 7, generator=torch.Generator().manual_seed(3), dtype=F64)
    for winner in range(5):
        index = torch.full((2, 1, 6, 7), winner, dtype=torch.long)
        assert torch.equal(subpixel_refine(cost, winner, method), subpixel_refine(cost, index, method))
    with pytest.raises(OptionError, match=r"index must be in \[0, 5\)"):
        subpixel_refine(cost, 5, method)


def test_soft_argmin_local():
    x = torch.arange(12, dtype=F64).view(1, 12, 1, 1)
    cost = ((x - 5.3) ** 2).expand(1, 12, 2, 3).clone()
    est = soft_argmin_local(cost, radius=2, temperature=0.5)
    assert est.shape == (1, 1, 2, 3) and (est - 5.3).abs().max() < 0.15
    # a distant second minimum does not bias the local estimate
    cost2 = cost.clone()
    cost2[:, 11] = -1.0
    near = soft_argmin_local(cost2, index=torch.full((1, 1, 2, 3), 5, dtype=torch.long), radius=2, temperature=0.5)
    torch.testing.assert_close(near, est)
    c = cost[:, :, :1, :1].clone().requires_grad_(True)
    assert torch.autograd.gradcheck(lambda t: soft_argmin_local(t, radius=2, temperature=0.7), (c,))
    with pytest.raises(OptionError, match="radius >= 1 and temperature > 0"):
        soft_argmin_local(cost, radius=0)


def test_uniqueness_and_confidence():
    cost = torch.tensor([1.0, 0.2, 0.25, 1.0, 0.21]).view(1, 5, 1, 1)
    idx, _ = winner_take_all(cost)
    unique, conf = uniqueness(cost, idx, 0.9)
    assert not bool(unique) and float(conf) < 0.1  # a second, distant minimum almost as good
    cost[0, 4] = 0.9
    unique, conf = uniqueness(cost, idx, 0.9)
    assert bool(unique) and 0 < float(conf) <= 1
    with pytest.raises(OptionError, match=r"ratio must be in \(0, 1\]"):
        uniqueness(cost, idx, 1.5)


@pytest.mark.parametrize("d", [3, 4, 9])
def test_uniqueness_of_nonnegative_costs_is_the_same(d):
    """The Max-masked form for costs >= 0 (a Where less in onnxruntime) gives the Where form's results exactly,
    zeros, ties and a winner whose neighbours cover every hypothesis (D = 3) included."""
    gen = torch.Generator().manual_seed(d)
    cost = torch.rand(2, d, 6, 7, generator=gen)
    cost[0, :, 0, 0] = 0.0  # all equal (zero)
    cost[1, 0, 1, 1] = cost[1, d - 1, 1, 1] = 0.0  # two distant minima
    idx, _ = winner_take_all(cost)
    for ratio in (0.5, 1.0):
        default, masked = uniqueness(cost, idx, ratio), uniqueness(cost, idx, ratio, nonnegative=True)
        for a, b in zip(default, masked, strict=True):
            assert torch.equal(a, b)


def test_left_right_check_rejects_occlusion():
    # left disparity 4 everywhere except an occluded band whose (wrong) disparity points at a surface
    # with another disparity in the right view
    dl = torch.full((1, 1, 1, 30), 4.0)
    dr = torch.full((1, 1, 1, 30), 4.0)
    dl[..., 15:18] = 8.0  # occluded pixels matched to the background
    ok = left_right_check(dl, dr, 1.0)
    assert not ok[..., :4].any()  # matches fall left of the right image
    assert ok[..., 4:15].all() and not ok[..., 15:18].any() and ok[..., 18:].all()
