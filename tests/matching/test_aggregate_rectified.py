import pytest
import torch

from prismstereo import OptionError, ShapeError
from prismstereo.matching import box_filter, sgm_aggregate
from prismstereo.matching.rectified import MatchOptions, match_rectified, right_view_volume
from tests.matching.test_cost_select import shifted_pair

F64 = torch.float64


def naive_path(cost, p1, p2, dx, dy):
    """Direct transcription of the SGM recursion for one direction (reference implementation)."""
    b, d, h, w = cost.shape
    out = torch.zeros_like(cost)
    xs = range(w) if dx >= 0 else range(w - 1, -1, -1)
    ys = range(h) if dy >= 0 else range(h - 1, -1, -1)
    for y in ys:
        for x in xs:
            px, py = x - dx, y - dy
            for k in range(d):
                c = cost[0, k, y, x]
                if not (0 <= px < w and 0 <= py < h):
                    out[0, k, y, x] = c
                    continue
                prev = out[0, :, py, px]
                cands = [prev[k], prev.min() + p2]
                if k > 0:
                    cands.append(prev[k - 1] + p1)
                if k < d - 1:
                    cands.append(prev[k + 1] + p1)
                out[0, k, y, x] = c + min(cands) - prev.min()
    return out


def test_sgm_matches_reference_recursion():
    gen = torch.Generator().manual_seed(0)
    cost = torch.rand(1, 5, 4, 6, generator=gen, dtype=F64)
    expected = sum(naive_path(cost, 0.3, 1.1, dx, dy) for dx, dy in ((1, 0), (-1, 0), (0, 1), (0, -1)))
    torch.testing.assert_close(sgm_aggregate(cost, 0.3, 1.1, 4), expected)
    diagonals = ((1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (1, -1), (-1, 1), (-1, -1))
    expected8 = sum(naive_path(cost, 0.3, 1.1, dx, dy) for dx, dy in diagonals)
    torch.testing.assert_close(sgm_aggregate(cost, 0.3, 1.1, 8), expected8)
    expected2 = naive_path(cost, 0.3, 1.1, 1, 0) + naive_path(cost, 0.3, 1.1, -1, 0)
    torch.testing.assert_close(sgm_aggregate(cost, 0.3, 1.1, 2), expected2)


def test_sgm_errors():
    with pytest.raises(OptionError, match="directions must be one of"):
        sgm_aggregate(torch.rand(1, 3, 4, 4), 0.1, 0.2, 6)
    with pytest.raises(OptionError, match="need 0 <= p1 <= p2"):
        sgm_aggregate(torch.rand(1, 3, 4, 4), 0.5, 0.2)
    with pytest.raises(OptionError, match="positive odd int"):
        box_filter(torch.rand(1, 3, 4, 4), 2)


def test_right_view_volume():
    vol = torch.arange(12.0).view(1, 3, 1, 4)
    right = right_view_volume(vol)
    assert right[0, 0, 0].tolist() == [0, 1, 2, 3]
    assert right[0, 2, 0].tolist() == [10, 11, float("inf"), float("inf")]


@pytest.mark.parametrize("cost", ["census", "sad", "zncc"])
def test_match_rectified_constant_shift(cost):
    left, right = shifted_pair(6.4, h=48, w=140, seed=2)
    res = match_rectified(left, right, 16, MatchOptions(cost=cost, window=9 if cost == "zncc" else 5))
    inner = res.valid[..., 8:-8, 24:-8]
    assert inner.float().mean() > 0.95
    err = (res.disparity[..., 8:-8, 24:-8] - 6.4)[inner].abs()
    assert err.median() < 0.1 and err.quantile(0.95) < 0.3
    assert ((res.confidence > 0) == res.valid).all()


def test_left_right_check_rejects_occlusion_in_a_step_pair():
    # background at disparity 3, a foreground strip at disparity 11: in the left view, the background just
    # left of the strip is hidden from the right view (occluded) and must be rejected
    bg_l, bg_r = shifted_pair(3.0, h=40, w=150, seed=3)
    fg_l, fg_r = shifted_pair(11.0, h=40, w=150, seed=4)
    left, right = bg_l.clone(), bg_r.clone()
    left[..., 80:120] = fg_l[..., 80:120]
    right[..., 69:109] = fg_l[..., 80:120]
    res = match_rectified(left, right, 16)
    occluded = res.valid[..., 5:-5, 72:79]  # background pixels whose right view is covered by the strip
    assert occluded.float().mean() < 0.2
    visible = res.valid[..., 5:-5, 30:60]
    assert visible.float().mean() > 0.9
    torch.testing.assert_close(res.disparity[..., 5:-5, 90:110][res.valid[..., 5:-5, 90:110]].median(),
                               torch.tensor(11.0, dtype=F64), atol=0.1, rtol=0)


def test_match_errors():
    a = torch.rand(1, 1, 8, 20)
    with pytest.raises(ShapeError, match="must have the same shape"):
        match_rectified(a, torch.rand(1, 1, 8, 21), 4)
    with pytest.raises(OptionError, match=r"num_disparities must be an int in \[2, W\)"):
        match_rectified(a, a, 40)
    with pytest.raises(OptionError, match="Unknown aggregation 'mgm'"):
        MatchOptions(aggregation="mgm")
    with pytest.raises(OptionError, match="box must be a positive odd int"):
        MatchOptions(box=4)
