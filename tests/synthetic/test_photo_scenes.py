from pathlib import Path

import pytest
import torch

from prismstereo.synthetic import HeightField, Plane, SceneError, disparity_scene, height_field_scene, middlebury_scene
from tests.synthetic.test_scenes import TEX, rays

F64 = torch.float64
MIDDLEBURY = Path(__file__).resolve().parents[3] / "shared" / "data" / "middlebury"


def test_height_field_matches_the_plane_it_samples():
    o, d = rays(2000)
    # a ramp: depth = 600 + 0.5 x, sampled on a grid; bilinear interpolation reproduces it exactly
    xs = (torch.arange(64, dtype=F64) + 0.5) * 100.0 / 64 - 50.0
    depth = (600.0 + 0.5 * xs)[None].expand(48, -1).contiguous()
    field = HeightField(depth, TEX, (-50.0, 50.0), (-37.5, 37.5))
    hit = field.intersect(o, d)
    plane = Plane((0.0, 0.0, 600.0), (-0.5, 0.0, 1.0), TEX).intersect(o, d)
    inside = (plane.points[:, 0].abs() < 49.0) & (plane.points[:, 1].abs() < 37.0)
    assert inside.float().mean() > 0.5
    assert torch.isfinite(hit.t[inside]).all()
    torch.testing.assert_close(hit.points[inside], plane.points[inside], atol=1e-6, rtol=0)
    outside = (plane.points[:, 0].abs() > 51.0) | (plane.points[:, 1].abs() > 39.0)
    assert torch.isinf(hit.t[outside]).all()


def test_height_field_occlusion_takes_first_crossing():
    # a tall box in the middle of a far floor: rays through it stop at its top surface
    depth = torch.full((40, 40), 800.0, dtype=F64)
    depth[15:25, 15:25] = 500.0
    field = HeightField(depth, TEX, (-40.0, 40.0), (-40.0, 40.0))
    o = torch.tensor([[0.0, 0.0, 175.0], [30.0, 30.0, 175.0]], dtype=F64)
    d = torch.tensor([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]], dtype=F64)
    torch.testing.assert_close(field.intersect(o, d).points[:, 2], torch.tensor([500.0, 800.0], dtype=F64))


def test_height_field_errors():
    with pytest.raises(SceneError, match="finite and positive"):
        HeightField(torch.zeros(4, 4), TEX, (-1, 1), (-1, 1))
    with pytest.raises(SceneError, match="increasing"):
        HeightField(torch.ones(4, 4), TEX, (1, -1), (-1, 1))
    with pytest.raises(SceneError, match=r"\(h, w\) tensor"):
        HeightField(torch.ones(4), TEX, (-1, 1), (-1, 1))


@pytest.mark.parametrize(
    "make,match",
    [
        (lambda: height_field_scene(torch.ones(4, 4) * 500, torch.zeros(1, 0, 4), 10.0), "same \\(h, w\\)"),
        (lambda: height_field_scene(torch.ones(0, 4), torch.zeros(0, 4), 10.0), "non-empty"),
        (lambda: middlebury_scene("/nonexistent"), "must hold img_left.png"),
        (lambda: disparity_scene(torch.rand(4, 4), torch.full((4, 4), float("nan"))), "no usable values"),
        (lambda: disparity_scene(torch.rand(4, 5), torch.rand(4, 4)), "picture's size"),
        (lambda: disparity_scene([[0.5]], torch.rand(4, 4)), "must be tensors"),
        (lambda: disparity_scene(torch.rand(4, 4), torch.rand(4, 4), 700.0, 450.0), "near_mm must be smaller"),
    ],
)
def test_factory_errors(make, match):
    with pytest.raises(SceneError, match=match):
        make()


def test_disparity_scene_maps_inverse_depth_linearly_and_inpaints():
    disparity = torch.linspace(10.0, 30.0, 40).expand(30, 40).clone()
    disparity[10:14, 20:24] = float("inf")  # unknown: inpainted from its neighbours
    disparity[0, 0] = 0.0
    field = disparity_scene(torch.rand(3, 30, 40), disparity, 400.0, 800.0, width_mm=120.0, name="ramp").surfaces[0]
    inverse = 1.0 / field.depth.double()
    expected = 1 / 800 + (disparity.double() - 10.0) / 20.0 * (1 / 400 - 1 / 800)  # 1/Z linear in disparity
    known = torch.isfinite(disparity) & (disparity > 0)
    torch.testing.assert_close(inverse[known], expected[known], rtol=1e-5, atol=0.0)
    hole = field.depth[10:14, 20:24]  # between its neighbours' depths (they fall from left to right)
    assert field.depth[10:14, 24].min() <= hole.min() and hole.max() <= field.depth[10:14, 19].max()
    assert field.texture.channels == 3 and field.x_range == (-60.0, 60.0)


@pytest.mark.skipif(not MIDDLEBURY.exists(), reason="shared Middlebury data not present")
def test_middlebury_scene_depths():
    scene = middlebury_scene(MIDDLEBURY / "Tsukuba", near_mm=450.0, far_mm=700.0)
    field = scene.surfaces[0]
    assert field.depth.shape == (288, 384)
    assert field.z_min == pytest.approx(450.0, abs=1e-3) and field.z_max == pytest.approx(700.0, abs=1e-3)
    assert field.texture.channels == 1 and field.x_range[1] - field.x_range[0] == pytest.approx(700 * 4.7616 / 25)
