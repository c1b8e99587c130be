"""The rectified-pair matcher's cost-volume filtering path: the 'ad_gradient' cost, the guided filter and the
defaults of :func:`match_rectified` built on them (the census / SGM path: test_aggregate_rectified.py)."""

import pytest
import torch

from prismstereo import OptionError, ShapeError
from prismstereo.matching.aggregate import guided_filter
from prismstereo.matching.cost import ad_gradient_volume
from prismstereo.matching.rectified import MatchOptions, match_rectified
from tests.matching.test_cost_select import shifted_pair

F64 = torch.float64


def test_ad_gradient_volume_reference_values():
    ref = torch.tensor([0.0, 0.5, 1.0], dtype=F64).view(1, 1, 1, 3)
    # gradients (edges replicated): 0.25, 0.5, 0.25; offset -1 compares u with u - 1
    vol = ad_gradient_volume(ref, ref.clone(), torch.tensor([0, -1]), 1.0, 1.0, 0.5)
    assert vol.cost.dtype == F64 and vol.cost.shape == (1, 2, 1, 3)
    torch.testing.assert_close(vol.cost[0, :, 0], torch.tensor([[0.0, 0.0, 0.0], [1.0, 0.375, 0.375]], dtype=F64))
    assert vol.valid.flatten().tolist() == [True, True, True, False, True, True]
    # truncated: every term saturates -> the normalised maximum 1
    sat = ad_gradient_volume(ref, ref.clone(), torch.tensor([-1]), 0.1, 0.1, 0.3)
    torch.testing.assert_close(sat.cost[0, 0, 0, 1:], torch.ones(2, dtype=F64))


def test_ad_gradient_volume_finds_a_shift_and_interpolates():
    left, right = shifted_pair(3.0, h=20, w=60, seed=1, channels=3)
    vol = ad_gradient_volume(left, right, -torch.arange(8.0))
    assert vol.cost.shape == (1, 8, 20, 60) and float(vol.cost.min()) >= 0 and float(vol.cost.max()) <= 1
    assert (vol.cost[..., 10:].argmin(1) == 3).float().mean() > 0.9
    half = ad_gradient_volume(left, right, torch.tensor([-2.5, -3.0]))  # fractional offsets interpolate
    assert half.valid.shape == (1, 2, 1, 60) and not half.valid[0, 0, 0, 2] and half.valid[0, 0, 0, 3]


def test_ad_gradient_volume_errors():
    a = torch.rand(1, 1, 4, 6)
    with pytest.raises(ShapeError, match="must share B, C, H"):
        ad_gradient_volume(a, torch.rand(1, 1, 5, 6), torch.tensor([0]))
    with pytest.raises(ShapeError, match="offsets must have shape"):
        ad_gradient_volume(a, a, torch.zeros(2, 2))
    with pytest.raises(OptionError, match="ad_threshold and gradient_threshold must be > 0"):
        ad_gradient_volume(a, a, torch.tensor([0]), 0.0)
    with pytest.raises(OptionError, match=r"gradient_weight must be in \[0, 1\]"):
        ad_gradient_volume(a, a, torch.tensor([0]), gradient_weight=1.5)


def naive_guided_filter(p, guide, r, eps):
    """Direct transcription of the guided filter, one window at a time (windows cut at the border)."""
    _, c, h, w = guide.shape
    a = torch.zeros(c, h, w, dtype=F64)
    b = torch.zeros(h, w, dtype=F64)
    for y in range(h):
        for x in range(w):
            ys, xs = slice(max(y - r, 0), y + r + 1), slice(max(x - r, 0), x + r + 1)
            g = guide[0, :, ys, xs].reshape(c, -1)
            v = p[ys, xs].reshape(-1)
            mg, mv = g.mean(1), v.mean()
            cov = (g - mg[:, None]) @ (g - mg[:, None]).T / g.shape[1] + eps * torch.eye(c, dtype=F64)
            a[:, y, x] = torch.linalg.solve(cov, (g - mg[:, None]) @ (v - mv) / g.shape[1])
            b[y, x] = mv - a[:, y, x] @ mg
    out = torch.zeros(h, w, dtype=F64)
    for y in range(h):
        for x in range(w):
            ys, xs = slice(max(y - r, 0), y + r + 1), slice(max(x - r, 0), x + r + 1)
            out[y, x] = a[:, ys, xs].mean((1, 2)) @ guide[0, :, y, x] + b[ys, xs].mean()
    return out


@pytest.mark.parametrize("channels", [1, 3])
def test_guided_filter_matches_the_reference(channels):
    gen = torch.Generator().manual_seed(3)
    guide = torch.rand(1, channels, 6, 7, generator=gen, dtype=F64)
    volume = torch.rand(2, 3, 6, 7, generator=gen, dtype=F64)
    out = guided_filter(volume, guide, 1, 1e-2)
    assert out.shape == volume.shape and out.dtype == F64
    for i in range(2):
        for k in range(3):
            torch.testing.assert_close(out[i, k], naive_guided_filter(volume[i, k], guide, 1, 1e-2))


def test_guided_filter_keeps_constants_and_edges():
    guide = torch.zeros(1, 3, 16, 20, dtype=F64)
    guide[..., 10:] = 1.0
    const = torch.full((1, 2, 16, 20), 0.7, dtype=F64)
    for s in (1, 2, 3):
        torch.testing.assert_close(guided_filter(const, guide, 4, 1e-4, s), const)
    step = torch.where(guide[:, :2] > 0, 1.0, 0.0) + 0.05 * torch.rand(1, 2, 16, 20, dtype=F64)
    for s in (1, 2):
        out = guided_filter(step, guide, 4, 1e-4, s)
        assert float(out[..., :10].max()) < 0.1 and float(out[..., 10:].min()) > 0.95  # no bleeding across the edge
    # a batch-1 guide serves every batch item
    two = guided_filter(torch.cat([step, 2 * step]), guide, 4, 1e-4)
    torch.testing.assert_close(two[1], 2 * two[0])


def test_guided_filter_errors():
    vol, guide = torch.rand(1, 2, 6, 7), torch.rand(1, 1, 6, 7)
    with pytest.raises(ShapeError, match="must match the volume"):
        guided_filter(vol, torch.rand(1, 1, 6, 8))
    with pytest.raises(ShapeError, match="volume must have shape"):
        guided_filter(torch.rand(2, 6, 7), guide)
    with pytest.raises(OptionError, match="radius must be an int >= 1"):
        guided_filter(vol, guide, 0)
    with pytest.raises(OptionError, match="subsample must be an int >= 1"):
        guided_filter(vol, guide, 2, 1e-4, 0)
    with pytest.raises(OptionError, match="eps must be > 0"):
        guided_filter(vol, guide, 2, 0.0)


@pytest.mark.parametrize("disparity", [6.0, 6.2, 6.5, 6.7])
def test_defaults_are_subpixel_accurate(disparity):
    # the truncated 'ad_gradient' cost locks fits on it to integers (0.15-0.2 px here); the default fit on the
    # untruncated colour difference does not
    left, right = shifted_pair(disparity, h=48, w=140, seed=2, channels=3)
    res = match_rectified(left, right, 16)
    inner = res.valid[..., 8:-8, 24:-8]
    assert inner.float().mean() > 0.95
    err = (res.disparity[..., 8:-8, 24:-8] - disparity)[inner].abs()
    assert err.median() < 0.03 and err.quantile(0.95) < 0.1
    locked = match_rectified(left, right, 16, MatchOptions(subpixel_cost="local", subpixel_window=1))
    if disparity in (6.2, 6.7):
        assert (locked.disparity[..., 8:-8, 24:-8] - disparity).abs().median() > 0.1


def test_defaults_fill_the_left_border_from_its_right():
    left, right = shifted_pair(6.4, h=48, w=140, seed=2)
    for out_of_range in ("replicate", "worst"):  # the filter's left-right check rejects the border either way
        res = match_rectified(left, right, 16, MatchOptions(out_of_range=out_of_range))
        assert res.filled[..., :6].all() and not res.valid[..., :6].any()
        assert (res.disparity[..., 8:-8, :7] - 6.4).abs().max() < 0.5


def test_every_aggregation_and_cost_runs():
    left, right = shifted_pair(4.0, h=32, w=80, seed=6, channels=3)
    for opts in (MatchOptions(aggregation="box", box=5), MatchOptions(cost="census"),
                 MatchOptions(cost="zncc", window=9), MatchOptions(weighted_median=0, lr_threshold=None),
                 MatchOptions(fill=False), MatchOptions(guided_subsample=1, weighted_median_step=1)):
        res = match_rectified(left.float(), right.float(), 8, opts)
        assert res.disparity.dtype == torch.float32 and res.disparity.shape == (1, 1, 32, 80)
        assert (res.disparity[..., 6:-6, 10:-6] - 4.0).abs().median() < 0.1


def test_match_options_errors():
    with pytest.raises(OptionError, match="Unknown cost 'ssd'. Choose from: 'sad', 'zncc', 'census', 'ad_gradient'"):
        MatchOptions(cost="ssd")
    with pytest.raises(OptionError, match="Unknown aggregation 'mgm'. Choose from: 'box', 'sgm', 'guided'"):
        MatchOptions(aggregation="mgm")
    with pytest.raises(OptionError, match="Unknown subpixel_cost 'ssd'. Choose from: 'local', 'sad'"):
        MatchOptions(subpixel_cost="ssd")
    with pytest.raises(OptionError, match="guided_radius must be an int >= 1"):
        MatchOptions(guided_radius=0)
    with pytest.raises(OptionError, match="guided_subsample must be an int >= 1"):
        MatchOptions(guided_subsample=1.5)
    with pytest.raises(OptionError, match="weighted_median must be an int >= 0"):
        MatchOptions(weighted_median=-1)
    with pytest.raises(OptionError, match="weighted_median_step must be an int >= 1"):
        MatchOptions(weighted_median_step=0)
    for name in ("ad_threshold", "gradient_threshold", "guided_eps", "sigma_space", "sigma_colour"):
        with pytest.raises(OptionError, match=f"{name} must be > 0"):
            MatchOptions(**{name: 0.0})
    with pytest.raises(OptionError, match=r"gradient_weight must be in \[0, 1\]"):
        MatchOptions(gradient_weight=-0.1)
