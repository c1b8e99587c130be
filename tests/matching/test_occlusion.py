import pytest
import torch

from prismstereo.errors import OptionError, ShapeError
from prismstereo.matching import zbuffer_visible


def _scene():
    """Two images of 1 x 4 reference pixels on a 4-column other half starting at column 10: pixels 0 and 1 land
    on other-half pixel (1, 0), pixel 2 on (3, 0), pixel 3 beyond the right edge (clamped to (3, 0))."""
    u = torch.tensor([11.2, 10.6, 13.0, 20.0])
    match = torch.stack([u, torch.zeros(4)]).view(1, 2, 1, 4).repeat(2, 1, 1, 1)
    depth = torch.tensor([500.0, 450.0, 600.0, 700.0]).view(1, 1, 1, 4).repeat(2, 1, 1, 1)
    valid = torch.ones(2, 1, 1, 4, dtype=torch.bool)
    return match, depth, valid


def test_the_nearest_point_claiming_an_other_half_pixel_hides_the_others():
    match, depth, valid = _scene()
    visible = zbuffer_visible(match, depth, valid, split=10, other_width=4)
    assert visible.shape == depth.shape and visible.dtype == torch.bool
    assert visible[0, 0, 0].tolist() == [False, True, True, False]  # 500 behind 450; 700 behind 600 (clamped)
    assert torch.equal(visible[0], visible[1])  # images are independent and alike here


def test_tolerance_invalid_pixels_and_occluders():
    match, depth, valid = _scene()
    assert zbuffer_visible(match, depth, valid, 10, 4, tolerance=0.15)[0, 0, 0].tolist() == [True, True, True, True]
    valid[1, 0, 0, 1] = False  # an invalid pixel hides nothing
    assert zbuffer_visible(match, depth, valid, 10, 4)[1, 0, 0, 0]
    occluders = valid.clone()
    occluders[0, 0, 0, 2] = False  # only chosen pixels hide others: 700 is no longer behind an occluder
    out = zbuffer_visible(match, depth, valid, 10, 4, occluders=occluders)
    assert out[0, 0, 0].tolist() == [False, True, True, True]


def test_errors():
    match, depth, valid = _scene()
    with pytest.raises(ShapeError, match="match"):
        zbuffer_visible(match[:, :1], depth, valid, 10, 4)
    with pytest.raises(ShapeError, match="valid must be a bool tensor"):
        zbuffer_visible(match, depth, valid.float(), 10, 4)
    with pytest.raises(ShapeError, match="occluders must be a bool tensor"):
        zbuffer_visible(match, depth, valid, 10, 4, occluders=valid[:1])
    with pytest.raises(ShapeError, match="does not match depth"):
        zbuffer_visible(match[..., :3], depth, valid, 10, 4)
    with pytest.raises(OptionError, match="tolerance must be >= 0"):
        zbuffer_visible(match, depth, valid, 10, 4, tolerance=-0.1)
    with pytest.raises(OptionError, match="other_width must be a positive int"):
        zbuffer_visible(match, depth, valid, 10, 0)


def test_exported_graph_matches_eager(tmp_path):
    """In an ONNX export the scatter is one ScatterElements (reduction 'min') without the exporter's If around it,
    the indices int32; onnxruntime gives the eager result, NaN matches included (clamped into the buffer)."""
    onnx = pytest.importorskip("onnx")
    ort = pytest.importorskip("onnxruntime")
    gen = torch.Generator().manual_seed(6)
    match = torch.stack([torch.rand(2, 6, 5, generator=gen) * 7 + 9, torch.rand(2, 6, 5, generator=gen) * 6], 1)
    match[0, :, 2, 3] = float("nan")
    depth = 400 + 100 * torch.rand(2, 1, 6, 5, generator=gen)
    valid = torch.rand(2, 1, 6, 5, generator=gen) > 0.2

    class Graph(torch.nn.Module):
        def forward(self, m, z, ok):
            return zbuffer_visible(m, z, ok, split=10, other_width=4, tolerance=0.01, occluders=ok & (z < 480))

    path = tmp_path / "zbuffer.onnx"
    torch.onnx.export(Graph(), (match, depth, valid), str(path), input_names=["m", "z", "ok"], opset_version=18,
                      dynamo=False)
    nodes = onnx.load(str(path)).graph.node
    assert [n.op_type for n in nodes].count("ScatterElements") == 1 and "If" not in {n.op_type for n in nodes}
    got = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"]).run(
        None, {"m": match.numpy(), "z": depth.numpy(), "ok": valid.numpy()})[0]
    want = Graph()(match, depth, valid)
    assert 0 < int(want.sum()) < want.numel() and torch.equal(torch.from_numpy(got), want)
