import pytest
import torch

from prismstereo import OptionError, ShapeError
from prismstereo.classical.rectified import MatchOptions, match_rectified
from prismstereo.matching import box_filter, box_std, sgm_aggregate, sgm_aggregate_guided
from tests.matching.test_cost_select import shifted_pair

F64 = torch.float64


def naive_path(cost, p1, p2, dx, dy, guide=None, edge=None):
    """Direct transcription of the SGM recursion for one direction (reference implementation); with a
    guide, P2 of the step q -> p is max(p1, p2 / (1 + max_c |guide_p - guide_q| / edge))."""
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
                jump = p2
                if guide is not None:
                    step = float((guide[0, :, y, x] - guide[0, :, py, px]).abs().max())
                    jump = max(p1, p2 / (1 + step / edge))
                cands = [prev[k], prev.min() + jump]
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


@pytest.mark.parametrize("directions", [2, 4, 8])
def test_sgm_without_autograd_equals_the_differentiable_form(directions):
    """Without autograd the scans write into preallocated buffers and sum in place; with autograd they stay
    functional: bitwise the same values (plain and guided), and float64 gradcheck of the functional form."""
    gen = torch.Generator().manual_seed(4)
    cost = torch.rand(2, 6, 9, 7, generator=gen, dtype=F64, requires_grad=True)
    guide = torch.rand(2, 1, 9, 7, generator=gen, dtype=F64)
    with_grad = sgm_aggregate(cost, 0.3, 1.1, directions)
    guided = sgm_aggregate_guided(cost, guide, 0.3, 1.1, 0.1, directions)
    assert with_grad.requires_grad and guided.requires_grad
    with torch.no_grad():
        assert torch.equal(sgm_aggregate(cost, 0.3, 1.1, directions), with_grad)
        assert torch.equal(sgm_aggregate_guided(cost, guide, 0.3, 1.1, 0.1, directions), guided)
    torch.autograd.gradcheck(lambda c: sgm_aggregate(c, 0.3, 1.1, directions), (cost[:1, :4, :5, :4],))


def test_box_and_sgm_exported_graphs_match_eager(tmp_path):
    """The ONNX forms (AveragePool for the box, MaxPool for SGM's neighbour term) compute what the eager forms
    (in-place shifted sums, -inf-padded Maximum) compute, and the box is the k x k mean of the pixels
    inside the image."""
    ort = pytest.importorskip("onnxruntime")
    gen = torch.Generator().manual_seed(3)
    cost = torch.rand(2, 7, 9, 11, generator=gen)
    ref = torch.nn.functional.avg_pool2d(cost.double(), 5, 1, 2, count_include_pad=False)
    torch.testing.assert_close(box_filter(cost.double(), 5), ref)

    class Graph(torch.nn.Module):
        def forward(self, volume: torch.Tensor) -> torch.Tensor:
            return sgm_aggregate(box_filter(volume, 5), 0.3, 1.1, 8)

    path = tmp_path / "agg.onnx"
    torch.onnx.export(Graph(), (cost,), str(path), input_names=["volume"], opset_version=18, dynamo=False)
    ops = {node.op_type for node in __import__("onnx").load(str(path)).graph.node}
    assert {"AveragePool", "MaxPool"} <= ops and "Conv" not in ops
    # the directions of one shape share one scan: W-axis pair, H-axis pair, the four diagonals; one MaxPool
    # per step after the first (76 with one scan per direction)
    pools = sum(node.op_type == "MaxPool" for node in __import__("onnx").load(str(path)).graph.node)
    assert pools == (11 - 1) + (9 - 1) + (11 - 1)
    out = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"]).run(None, {"volume": cost.numpy()})[0]
    torch.testing.assert_close(torch.from_numpy(out), Graph()(cost), rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("grad", [False, True])
def test_stacked_scans_keep_batch_items_apart(grad):
    """The scans stack directions on the batch axis: each item of a batch (and a guide of batch 1 shared by
    all) gives what it gives alone, with and without autograd."""
    gen = torch.Generator().manual_seed(5)
    cost = torch.rand(3, 4, 6, 5, generator=gen, dtype=F64, requires_grad=grad)
    guide = torch.rand(1, 2, 6, 5, generator=gen, dtype=F64)
    for directions in (2, 4, 8):
        whole = sgm_aggregate_guided(cost, guide, 0.3, 1.1, 0.1, directions)
        plain = sgm_aggregate(cost, 0.3, 1.1, directions)
        for i in range(3):
            torch.testing.assert_close(whole[i:i + 1], sgm_aggregate_guided(cost[i:i + 1], guide, 0.3, 1.1, 0.1,
                                                                             directions), rtol=0, atol=0)
            torch.testing.assert_close(plain[i:i + 1], sgm_aggregate(cost[i:i + 1], 0.3, 1.1, directions),
                                       rtol=0, atol=0)


def test_guided_sgm_matches_reference_recursion():
    gen = torch.Generator().manual_seed(1)
    cost = torch.rand(1, 5, 5, 6, generator=gen, dtype=F64)
    guide = torch.rand(1, 3, 5, 6, generator=gen, dtype=F64)
    diagonals = ((1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (1, -1), (-1, 1), (-1, -1))
    expected = sum(naive_path(cost, 0.2, 1.5, dx, dy, guide, 0.1) for dx, dy in diagonals)
    torch.testing.assert_close(sgm_aggregate_guided(cost, guide, 0.2, 1.5, 0.1, 8), expected)
    # a uniform guide gives the constant-P2 aggregation
    torch.testing.assert_close(sgm_aggregate_guided(cost, torch.zeros(1, 1, 5, 6, dtype=F64), 0.2, 1.5, 0.1, 4),
                               sgm_aggregate(cost, 0.2, 1.5, 4))


def test_guided_sgm_keeps_a_step_at_an_edge():
    # strong evidence for hypothesis 1 on the left, weak evidence for 6 on the right: a constant P2 lets the
    # left side spread into the right one (fattening); with the jump cheap across the guide's edge it stops
    d, h, w = 8, 12, 24
    hyp = torch.arange(d, dtype=F64).view(1, d, 1, 1)
    column = torch.arange(w).view(1, 1, 1, w)
    cost = torch.where(column < 12, (hyp - 1).abs().clamp(max=1), 0.02 * (hyp - 6).abs().clamp(max=1))
    cost = cost.expand(1, d, h, w).contiguous()
    guide = (column >= 12).to(F64).expand(1, 3, h, w)
    smooth = sgm_aggregate(cost, 0.05, 1.0, 8).argmin(1)
    guided = sgm_aggregate_guided(cost, guide, 0.05, 1.0, 0.01, 8).argmin(1)
    assert (smooth[..., 12:] == 6).float().mean() < 0.7
    assert (guided[..., :12] == 1).all() and (guided[..., 12:] == 6).all()


def test_sgm_errors():
    with pytest.raises(OptionError, match="directions must be one of"):
        sgm_aggregate(torch.rand(1, 3, 4, 4), 0.1, 0.2, 6)
    with pytest.raises(OptionError, match="need 0 <= p1 <= p2"):
        sgm_aggregate(torch.rand(1, 3, 4, 4), 0.5, 0.2)
    with pytest.raises(OptionError, match="positive odd int"):
        box_filter(torch.rand(1, 3, 4, 4), 2)
    cost, guide = torch.rand(1, 3, 4, 4), torch.rand(1, 1, 4, 4)
    with pytest.raises(OptionError, match="edge must be > 0"):
        sgm_aggregate_guided(cost, guide, 0.1, 0.2, 0.0)
    with pytest.raises(OptionError, match="need 0 <= p1 <= p2"):
        sgm_aggregate_guided(cost, guide, 0.5, 0.2, 0.1)
    with pytest.raises(OptionError, match="directions must be one of"):
        sgm_aggregate_guided(cost, guide, 0.1, 0.2, 0.1, 3)
    with pytest.raises(ShapeError, match="must match the cost"):
        sgm_aggregate_guided(cost, torch.rand(1, 1, 4, 5), 0.1, 0.2, 0.1)


@pytest.mark.parametrize("cost", ["census", "sad", "zncc"])
def test_match_rectified_constant_shift(cost):
    left, right = shifted_pair(6.4, h=48, w=140, seed=2)
    res = match_rectified(left, right, 16, MatchOptions().with_options(cost=cost, window=9 if cost == "zncc" else 5))
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
    base = MatchOptions()
    with pytest.raises(OptionError, match="Unknown aggregation 'mgm'"):
        base.with_options(aggregation="mgm")
    with pytest.raises(OptionError, match="box must be a positive odd int"):
        base.with_options(box=4)
    with pytest.raises(OptionError, match="median must be a positive odd int"):
        MatchOptions(median=0)
    with pytest.raises(OptionError, match="subpixel_window must be a positive odd int"):
        MatchOptions(subpixel_window=2)
    with pytest.raises(OptionError, match="census_threshold must be a number >= 0"):
        base.with_options(census_threshold=-0.01)
    with pytest.raises(OptionError, match="p2_edge must be a finite number > 0 or None"):
        base.with_options(p2_edge=0.0)
    with pytest.raises(OptionError, match=r"p2 must be a finite number >= p1 \(400.0\)"):
        base.with_options(p1=400.0)
    with pytest.raises(OptionError, match="Unknown out_of_range 'clamp'"):
        MatchOptions(out_of_range="clamp")
    with pytest.raises(OptionError, match="window must be an odd int >= 3"):
        match_rectified(a, a, 4, base.with_options(cost="census", window=1))


def step_pair():
    """Background at disparity 3, a foreground strip (left columns 80..119) at disparity 11."""
    bg_l, bg_r = shifted_pair(3.0, h=40, w=150, seed=3)
    fg_l, _ = shifted_pair(11.0, h=40, w=150, seed=4)
    left, right = bg_l.clone(), bg_r.clone()
    left[..., 80:120] = fg_l[..., 80:120]
    right[..., 69:109] = fg_l[..., 80:120]
    return left, right


def test_fill_gives_occluded_pixels_the_background():
    left, right = step_pair()
    res = match_rectified(left, right, 16)
    assert res.disparity.dtype == F64 and res.filled.dtype == torch.bool
    assert not (res.valid & res.filled).any()
    assert (res.valid | res.filled).all()  # dense
    band = res.disparity[..., 5:-5, 73:79]  # occluded background, rejected by the left-right check
    assert res.filled[..., 5:-5, 73:79].float().mean() > 0.9
    err = (band - 3.0).abs()
    assert err.median() < 0.3 and err.quantile(0.9) < 1.0  # background, not the foreground's 11
    off = match_rectified(left, right, 16, MatchOptions(fill=False))
    assert not off.filled.any() and not off.valid[..., 5:-5, 73:79].float().mean() > 0.2


def test_left_border_takes_the_disparity_of_its_right():
    # columns u < 6.4 have no match in the right image: with out-of-range hypotheses replicating the last
    # in-range cost SGM carries the disparity into them, the range check rejects them and the fill
    # completes them; with the worst cost they get small in-range disparities (6 px off), which only the
    # left-right check against the right view's own decision rejects
    left, right = shifted_pair(6.4, h=48, w=140, seed=2)
    res = match_rectified(left, right, 16)
    assert res.filled[..., :6].all() and not res.valid[..., :6].any()
    assert (res.disparity[..., 8:-8, :7] - 6.4).abs().max() < 0.5
    # (the census + SGM pipeline; the default guided-filter pipeline rejects and fills that border either way)
    census_sgm = MatchOptions().with_options(cost="census", aggregation="sgm", subpixel_cost="local",
                                             subpixel_window=3, weighted_median=0)
    for lr_threshold in (None, 1.0):
        replicate = match_rectified(left, right, 16, census_sgm.with_options(lr_threshold=lr_threshold))
        assert (replicate.disparity[..., 8:-8, :7] - 6.4).abs().max() < 0.5
    worst = census_sgm.with_options(out_of_range="worst")
    unchecked = match_rectified(left, right, 16, worst.with_options(lr_threshold=None))
    assert unchecked.valid[..., :6].all() and (unchecked.disparity[..., 8:-8, :7] - 6.4).abs().max() > 3
    checked = match_rectified(left, right, 16, worst)
    assert checked.filled[..., 8:-8, :6].float().mean() > 0.8
    assert (checked.disparity[..., 8:-8, :7] - 6.4).abs().max() < 1


def test_match_rectified_dtype_and_colour():
    left, right = shifted_pair(4.0, h=32, w=80, seed=6, channels=3)
    colour_census = MatchOptions().with_options(cost="census", aggregation="sgm", grey=False, p2_edge=None, median=1,
                                                census_threshold=0.0)
    for opts in (MatchOptions(), colour_census):
        res = match_rectified(left.float(), right.float(), 8, opts)
        assert res.disparity.dtype == torch.float32
        assert (res.disparity[..., 6:-6, 10:-6] - 4.0).abs().median() < 0.1


def test_box_std_is_the_window_standard_deviation():
    g = torch.Generator().manual_seed(4)
    image = torch.rand(1, 1, 9, 11, generator=g, dtype=torch.float64)
    std = box_std(image, 5)
    assert std.shape == image.shape
    torch.testing.assert_close(std[0, 0, 4, 5], image[0, 0, 2:7, 3:8].std(unbiased=False))
    torch.testing.assert_close(std[0, 0, 0, 0], image[0, 0, :3, :3].std(unbiased=False))  # cut at the border
    assert float(box_std(torch.full((1, 1, 6, 6), 0.3, dtype=torch.float64), 3).max()) <= 1e-6  # the floor
    flat = torch.full((1, 1, 6, 6), 0.3, dtype=torch.float64, requires_grad=True)
    box_std(flat, 3).sum().backward()
    assert bool(torch.isfinite(flat.grad).all())  # no infinite gradient of the root at 0
    assert float(box_std(torch.full((1, 1, 6, 6), 0.3), 3).max()) < 2e-4  # float32: E[x^2] - E[x]^2 cancels
    with pytest.raises(ShapeError):
        box_std(torch.rand(1, 2, 6, 6), 3)
