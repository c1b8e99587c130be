import numpy as np
import pytest
import torch

from prismstereo import OptionError, ShapeError
from prismstereo.matching.cost import Warped, sweep_cost, worst_cost
from prismstereo.matching.sweep_cost import sample_points, shift_cost, warp_slices
from prismstereo.runtime import flat_index, gather_bilinear


def _shift_grid(h: int, w: int, w_o: int, shifts: list[float]) -> torch.Tensor:
    """(1, D, h, w, 2) normalised grids sampling other column u + shift, row v."""
    v, u = torch.meshgrid(torch.arange(h, dtype=torch.float64), torch.arange(w, dtype=torch.float64), indexing="ij")
    grids = [torch.stack([(2 * (u + s) + 1) / w_o - 1, (2 * v + 1) / h - 1], -1) for s in shifts]
    return torch.stack(grids)[None]


def test_warp_slices_samples_columns_and_flags_outside():
    other = torch.arange(12.0, dtype=torch.float64).view(1, 1, 1, 12).expand(1, 1, 3, 12).contiguous()
    warped = warp_slices(other, _shift_grid(3, 8, 12, [0.0, 2.5, 6.0]))
    torch.testing.assert_close(warped.image[0, 0, 1, 0], torch.arange(8.0, dtype=torch.float64) + 2.5)
    assert warped.valid[0, 0].all() and warped.valid[0, 1].all()
    assert warped.valid[0, 2, 0].tolist() == [True] * 6 + [False] * 2  # columns 12, 13 are outside
    mask = torch.ones(3, 12, dtype=torch.bool)
    mask[:, 5] = False  # a pixel that sees nothing through the prism poisons both bilinear neighbours
    w2 = warp_slices(other, _shift_grid(3, 8, 12, [0.0, 0.5]), mask)
    assert w2.valid[0, 0, 0].tolist() == [True] * 5 + [False] + [True] * 2
    assert w2.valid[0, 1, 0].tolist() == [True] * 4 + [False, False] + [True] * 2


def test_shared_grid_matches_per_image_grids():
    gen = torch.Generator().manual_seed(1)
    other = torch.rand(3, 2, 10, 16, generator=gen, dtype=torch.float64)
    mask = torch.rand(10, 16, generator=gen) > 0.1
    grid = _shift_grid(10, 12, 16, [0.3, 1.7, 4.2])
    shared = warp_slices(other, grid, mask, shared=True)
    each = warp_slices(other, grid.expand(3, -1, -1, -1, -1), mask, shared=False)
    assert shared.image.shape == (3, 2, 3, 10, 12) and shared.valid.shape == (3, 3, 10, 12)
    torch.testing.assert_close(shared.image, each.image)
    assert torch.equal(shared.valid, each.valid)
    assert warp_slices(other, grid).valid.shape == (3, 3, 10, 12)  # batch-1 grid: shared by default
    with pytest.raises(ShapeError, match="a shared grid must have batch 1"):
        warp_slices(other, grid.expand(3, -1, -1, -1, -1), shared=True)


@pytest.mark.parametrize("cost", ["sad", "zncc", "census"])
def test_true_shift_has_the_lowest_cost(cost):
    gen = torch.Generator().manual_seed(0)
    other = torch.rand(2, 1, 20, 40, generator=gen, dtype=torch.float64)
    ref = other[..., 5:29]  # reference column u shows other column u + 5
    warped = warp_slices(other, _shift_grid(20, 24, 40, [3.0, 4.0, 5.0, 6.0, 7.0]))
    vol = sweep_cost(ref, warped, cost, 5)
    assert vol.shape == (2, 5, 20, 24)
    assert (vol.argmin(1) == 2).float().mean() > 0.97
    # exact match: 0, except ZNCC's variance floor, 1 - var / (var + 1e-5) (var ~ 1/12 for uniform noise)
    assert vol[:, 2].abs().max() < (3e-4 if cost == "zncc" else 1e-9)


def test_invalid_samples_get_the_worst_cost_and_errors():
    ref = torch.rand(1, 3, 6, 7, generator=torch.Generator().manual_seed(1))
    valid = torch.zeros(1, 2, 6, 7, dtype=torch.bool)
    slices = Warped(torch.rand(1, 3, 2, 6, 7), valid)
    assert (sweep_cost(ref, slices, "census", 3) == worst_cost("census", 3, 3)).all()
    assert worst_cost("census", 3, 3) == 24.0 and worst_cost("sad", 1, 5) == 1.0
    with pytest.raises(OptionError, match="'census'"):
        sweep_cost(ref, slices, "ssd", 5)
    with pytest.raises(OptionError, match="odd int"):
        sweep_cost(ref, slices, "census", 1)
    with pytest.raises(ShapeError, match="does not match"):
        sweep_cost(ref[..., :5], slices, "sad", 3)
    with pytest.raises(ShapeError, match="grid batch"):
        warp_slices(torch.rand(2, 1, 6, 7), torch.zeros(3, 2, 6, 7, 2))


def test_sad_and_zncc_are_differentiable():
    gen = torch.Generator().manual_seed(2)
    ref = torch.rand(1, 1, 6, 8, generator=gen, dtype=torch.float64, requires_grad=True)
    other = torch.rand(1, 1, 6, 10, generator=gen, dtype=torch.float64, requires_grad=True)
    grid = _shift_grid(6, 8, 10, [0.3, 1.6])
    for cost in ("sad", "zncc"):
        torch.autograd.gradcheck(lambda a, b, c=cost: sweep_cost(a, warp_slices(b, grid), c, 3), (ref, other))


@pytest.mark.parametrize("cost", ["zncc", "sad", "census"])
@pytest.mark.parametrize("transposed", [False, True])
def test_shift_cost_is_sweep_cost_on_shifted_slices(cost, transposed):
    """ZNCC's shortcut (moments gathered from the image) and the transposed layout change nothing: the volume
    equals sweep_cost on explicitly gathered slices, edges included; the true shift wins."""
    gen = torch.Generator().manual_seed(4)
    other = torch.rand(2, 1, 20, 40, generator=gen, dtype=torch.float64)
    reference = other[..., 6:36]  # reference column u = other column u + 6
    index = (torch.arange(30) + torch.arange(12).view(-1, 1)).clamp(max=39)
    valid = (torch.rand(1, 12, 20, 30, generator=gen) > 0.1) & (torch.arange(30) + torch.arange(12).view(-1, 1) < 40
                                                               ).view(1, 12, 1, 30)
    slices = Warped(other[..., index].permute(0, 1, 3, 2, 4), valid.expand(2, -1, -1, -1))
    expected = sweep_cost(reference, slices, cost, 5)
    vol = shift_cost(reference, other, index, valid.transpose(-1, -2) if transposed else valid, cost, 5,
                     transposed=transposed)
    torch.testing.assert_close(vol.transpose(-1, -2) if transposed else vol, expected)
    win = expected.masked_fill(~valid, 1e9).argmin(1)
    assert (win == 6)[valid[:, 6].expand_as(win)].double().mean() > 0.95
    # another cost for the entries that are not real samples (the rectified search's 3/4 of the worst): exactly
    # that there, the same volume elsewhere; a fill >= the worst cost is the default's bounded form
    valid_v = valid.transpose(-1, -2) if transposed else valid
    worst = worst_cost(cost, 1, 5)
    for fill in (0.75 * worst, 0.0, 3.0 * worst):
        filled = shift_cost(reference, other, index, valid_v, cost, 5, transposed=transposed, fill=fill)
        filled, default = (t.transpose(-1, -2) if transposed else t for t in (filled, vol))
        assert torch.equal(filled[valid.expand_as(filled)], default[valid.expand_as(default)])
        assert bool((filled[~valid.expand_as(filled)] == fill).all())


def test_shift_cost_gradients_and_errors():
    gen = torch.Generator().manual_seed(5)
    other = torch.rand(1, 1, 8, 14, generator=gen, dtype=torch.float64)
    reference = other[..., 2:12].clone().requires_grad_(True)
    index = (torch.arange(10) + torch.arange(4).view(-1, 1)).clamp(max=13)
    valid = torch.ones(1, 4, 8, 10, dtype=torch.bool)
    assert torch.autograd.gradcheck(lambda r: shift_cost(r, other, index, valid, "zncc", 3), (reference,))
    with pytest.raises(ShapeError, match="disagree"):
        shift_cost(reference, other, index[:, :5], valid)
    with pytest.raises(ShapeError, match="valid must be"):
        shift_cost(reference, other, index, valid, transposed=True)
    with pytest.raises(OptionError, match="'census'"):
        shift_cost(reference, other, index, valid, "ssd")
    with pytest.raises(OptionError, match="window must be a positive odd int"):
        shift_cost(reference, other, index, valid, "zncc", 4)
    with pytest.raises(OptionError, match="fill must be a number >= 0"):
        shift_cost(reference, other, index, valid, "zncc", 3, fill=-1.0)


def _bilinear_reference(image: torch.Tensor, x: float, y: float) -> torch.Tensor:
    """Textbook bilinear interpolation of (C, H, W) at a clamped pixel position."""
    h, w = image.shape[-2:]
    x, y = min(max(x, 0.0), w - 1.0), min(max(y, 0.0), h - 1.0)
    x0, y0 = int(x), int(y)
    x1, y1 = min(x0 + 1, w - 1), min(y0 + 1, h - 1)
    ax, ay = x - x0, y - y0
    top = (1 - ax) * image[:, y0, x0] + ax * image[:, y0, x1]
    bottom = (1 - ax) * image[:, y1, x0] + ax * image[:, y1, x1]
    return (1 - ay) * top + ay * bottom


@pytest.mark.parametrize("channels, width", [(1, 5), (3, 5), (1, 7)])
def test_sample_points_both_forms_are_bilinear_with_border_clamping(channels, width):
    # the gather form splits the samples of a one-channel image over rows (3 x 4 x 5: 2; 3 x 4 x 7: 1, as colour)
    gen = torch.Generator().manual_seed(3)
    image = torch.rand(2, channels, 7, 9, generator=gen, dtype=torch.float64)
    # inside, on the last row / column, and beyond every edge (border padding clamps)
    x = torch.rand(2, 3, 4, width, generator=gen, dtype=torch.float64) * 12 - 2
    y = torch.rand(2, 3, 4, width, generator=gen, dtype=torch.float64) * 10 - 2
    x[0, 0, 0, :3] = torch.tensor([8.0, 0.0, 8.0], dtype=torch.float64)
    y[0, 0, 0, :3] = torch.tensor([6.0, 6.0, 0.0], dtype=torch.float64)
    eager = sample_points(image, x, y)
    assert eager.shape == (2, channels, 3, 4, width)
    gathered = gather_bilinear(image, x, y)  # the ONNX form, run eagerly
    torch.testing.assert_close(gathered, eager)
    for b, j, r, c in [(0, 0, 0, 0), (0, 0, 0, 1), (0, 0, 0, 2), (1, 2, 3, 4), (1, 1, 2, 0)]:
        expected = _bilinear_reference(image[b], float(x[b, j, r, c]), float(y[b, j, r, c]))
        torch.testing.assert_close(eager[b, :, j, r, c], expected)


def test_sample_points_gradients_and_errors():
    gen = torch.Generator().manual_seed(4)
    image = torch.rand(1, 2, 5, 6, generator=gen, dtype=torch.float64, requires_grad=True)
    # positions away from pixel centres (bilinear is not differentiable across them)
    x = (torch.rand(1, 2, 3, 3, generator=gen, dtype=torch.float64) * 0.8 + 0.1 + torch.arange(3.0).view(1, 1, 1, 3)
         ).requires_grad_()
    y = (torch.rand(1, 2, 3, 3, generator=gen, dtype=torch.float64) * 0.8 + 1.1).requires_grad_()
    assert torch.autograd.gradcheck(sample_points, (image, x, y))
    assert torch.autograd.gradcheck(gather_bilinear, (image, x, y))
    with pytest.raises(ShapeError, match="must match"):
        sample_points(image, x, y[:, :1])
    with pytest.raises(ShapeError, match="batch"):
        sample_points(image.detach().expand(2, -1, -1, -1), x, y)
    with pytest.raises(ShapeError, match="x"):
        sample_points(image, x[0], y[0])


def test_sample_points_exported_graph_matches_eager(tmp_path):
    ort = pytest.importorskip("onnxruntime")
    onnx = pytest.importorskip("onnx")

    class Graph(torch.nn.Module):
        def forward(self, image: torch.Tensor, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
            return sample_points(image, x, y)

    gen = torch.Generator().manual_seed(5)
    image = torch.rand(2, 1, 12, 16, generator=gen)
    x = torch.rand(2, 5, 12, 10, generator=gen) * 18 - 1
    y = torch.rand(2, 5, 12, 10, generator=gen) * 14 - 1
    path = tmp_path / "sample.onnx"
    torch.onnx.export(Graph(), (image, x, y), str(path), input_names=["image", "x", "y"], opset_version=18,
                      dynamo=False)
    ops = {node.op_type for node in onnx.load(str(path)).graph.node}
    assert "GridSample" not in ops and "GatherElements" in ops  # the gather form
    session = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    out = session.run(None, {"image": image.numpy(), "x": x.numpy(), "y": y.numpy()})[0]
    torch.testing.assert_close(torch.from_numpy(out), sample_points(image, x, y), atol=1e-6, rtol=1e-6)
    x[0, 0, 0, 0] = float("nan")  # a NaN position gives a NaN sample, not an out-of-range gather
    out = session.run(None, {"image": image.numpy(), "x": x.numpy(), "y": y.numpy()})[0]
    assert np.isnan(out[0, 0, 0, 0, 0]) and np.isfinite(out).sum() == out.size - 1


def test_flat_index_int32_exact_and_clamped():
    """row * width + column as int32, exact beyond float32's 2^24 (integer arithmetic there), in float64 too,
    and clamped into the image (a NaN position still indexes a pixel)."""
    rows, cols = torch.tensor([0.0, 2.0, 2.0]), torch.tensor([3.0, 1.0, 3.0])
    index = flat_index(rows, cols, 4, 12)
    assert index.dtype == torch.int32 and index.tolist() == [3, 9, 11]
    assert flat_index(rows.double(), cols.double(), 4, 12).tolist() == [3, 9, 11]
    big = flat_index(torch.tensor([4999.0]), torch.tensor([4999.0]), 5001, 5001 * 5001)  # 25 004 998 > 2^24
    assert big.dtype == torch.int32 and big.item() == 4999 * 5001 + 4999
    odd = flat_index(torch.tensor([float("nan"), 5.0]), torch.tensor([0.0, 9.0]), 4, 12)
    assert 0 <= int(odd.min()) and int(odd.max()) <= 11
