"""The rectified-pair matcher: the depth model's shift volume and decision (shift_cost, decide) under the matcher's
options, its defaults (cost-volume filtering: the 'ad_gradient' cost and the guided filter) and their options (the
census / SGM path: test_aggregate_rectified.py)."""

import pytest
import torch

from prismstereo import OptionError, ShapeError
from prismstereo.classical.config import StereoConfig
from prismstereo.classical.rectified import MATCH_CONFIG, SHARED_OPTIONS, MatchOptions, match_rectified
from prismstereo.conventions import to_grey
from prismstereo.matching import decide, shift_cost
from prismstereo.matching.aggregate import guided_filter
from tests.matching.test_cost_select import shifted_pair

F64 = torch.float64
# the matcher without its own steps: what is left is the shared volume and decision
SHARED_ONLY = dict(out_of_range="worst", subpixel_cost=None, lr_threshold=None, median=1, fill=False, weighted_median=0)


@pytest.mark.parametrize("shared", [{}, {"cost": "census", "aggregation": "sgm"},
                                    {"cost": "zncc", "window": 9, "aggregation": "box", "box": 3,
                                     "refinement": "parabola", "min_uniqueness": 0.05}],
                         ids=["guided", "census-sgm-edges", "zncc-box"])
def test_match_rectified_is_the_shared_shift_cost_and_decide(shared):
    """Without its own steps the matcher's disparity, validity and confidence are bitwise those of shift_cost (left
    column u against right column u - d, real where u - d >= 0) and decide under its config (a final search guided by
    the colour left image): the depth model's volume and decision, not a copy of them."""
    h, w, d = 24, 64, 10
    left, right = shifted_pair(4.3, h=h, w=w, seed=7, channels=3)
    options = MatchOptions().with_options(**SHARED_ONLY, **shared)
    res = match_rectified(left, right, d, options)
    config = options.config
    grey = config.cost.cost in ("census", "sad")  # MatchOptions.grey: the census and SAD compare the images' grey
    ref, other = (to_grey(left), to_grey(right)) if grey else (left, right)
    column = torch.arange(w) - torch.arange(d).view(-1, 1)
    inside = (column >= 0).view(1, d, 1, w).expand(1, d, h, w)
    volume = shift_cost(ref, other, column.clamp_min(0), inside, config.cost.cost, config.cost.window,
                        config.cost.census_threshold)
    decision = decide(volume, config.decision_options(), ref.shape[1], final=True, guide=left)
    valid = decision.unique & inside.gather(1, decision.index)
    assert torch.equal(res.disparity, decision.refined)
    assert torch.equal(res.valid, valid)
    assert torch.equal(res.confidence, torch.where(valid, decision.confidence, torch.zeros_like(decision.confidence)))
    assert not res.filled.any()
    assert (res.disparity[..., 4:-4, 14:-4] - 4.3).abs().median() < 0.3  # (no SAD fit: some pixel locking)


def test_match_options_hold_the_shared_config_and_the_matchers_own_steps():
    options = MatchOptions()
    assert options.config == MATCH_CONFIG and isinstance(options.config, StereoConfig)
    changed = options.with_options(cost="census", box=5, guided_radius=9, min_uniqueness=0.2, median=3, fill=False)
    assert changed.config == MATCH_CONFIG.with_options(cost="census", box=5, guided_radius=9, min_uniqueness=0.2)
    assert (changed.median, changed.fill, changed.lr_threshold) == (3, False, 1.0)
    assert options.with_options(lr_threshold=None).lr_threshold is None  # the matcher's check, not the search's
    assert options.with_options(lr_threshold=None).config == MATCH_CONFIG
    # every shared option is an option of the config groups the depth model reads
    assert set(SHARED_OPTIONS) <= set(StereoConfig().to_options())
    with pytest.raises(OptionError, match="unknown matcher option.*'sampling'"):
        options.with_options(sampling="sweep")  # the depth model's search: not the matcher's
    with pytest.raises(OptionError, match="unknown matcher option.*'uniqueness_ratio'"):
        options.with_options(uniqueness_ratio=0.9)


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
    base = MatchOptions()
    for opts in (base.with_options(aggregation="box", box=5), base.with_options(cost="census"),
                 base.with_options(cost="zncc", window=9), base.with_options(weighted_median=0, lr_threshold=None),
                 base.with_options(fill=False), base.with_options(guided_subsample=1, weighted_median_step=1),
                 base.with_options(subpixel_cost=None, refinement="soft_argmin")):
        res = match_rectified(left.float(), right.float(), 8, opts)
        assert res.disparity.dtype == torch.float32 and res.disparity.shape == (1, 1, 32, 80)
        assert (res.disparity[..., 6:-6, 10:-6] - 4.0).abs().median() < 0.1


def test_match_options_errors():
    base = MatchOptions()
    with pytest.raises(OptionError, match="Unknown cost 'ssd'. Choose from: 'sad', 'zncc', 'census', 'ad_gradient'"):
        base.with_options(cost="ssd")
    with pytest.raises(OptionError, match="Unknown aggregation 'mgm'. Choose from: 'sgm', 'box', 'guided'"):
        base.with_options(aggregation="mgm")
    with pytest.raises(OptionError, match="Unknown subpixel_cost 'ssd'. Choose from: 'local', 'sad'"):
        MatchOptions(subpixel_cost="ssd")
    with pytest.raises(OptionError, match="guided_radius must be an int >= 1"):
        base.with_options(guided_radius=0)
    with pytest.raises(OptionError, match="guided_subsample must be an int >= 1"):
        base.with_options(guided_subsample=1.5)
    with pytest.raises(OptionError, match="weighted_median must be an int >= 0"):
        MatchOptions(weighted_median=-1)
    with pytest.raises(OptionError, match="weighted_median_step must be an int >= 1"):
        MatchOptions(weighted_median_step=0)
    with pytest.raises(OptionError, match="guided_eps must be a finite number > 0"):
        base.with_options(guided_eps=0.0)
    for name in ("sigma_space", "sigma_colour"):
        with pytest.raises(OptionError, match=f"{name} must be a finite number > 0"):
            MatchOptions(**{name: 0.0})
    with pytest.raises(OptionError, match="lr_threshold must be a finite number > 0 or None"):
        MatchOptions(lr_threshold=0.0)
    with pytest.raises(OptionError, match="config must be a StereoConfig"):
        MatchOptions(config="dense")
    with pytest.raises(OptionError, match="fill must be a bool"):
        MatchOptions(fill=1)
