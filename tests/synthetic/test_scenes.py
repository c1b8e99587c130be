import math
from pathlib import Path

import pytest
import torch

from prismstereo import thesis_setup1
from prismstereo.synthetic import (
    ConstantTexture,
    HeightField,
    Plane,
    Scene,
    SceneError,
    Sphere,
    checkerboard_target,
    circle_grid_target,
    disparity_scene,
    fronto_parallel_plane,
    height_field_scene,
    middlebury_scene,
    slanted_plane,
    sphere_scene,
    step_scene,
)

F64 = torch.float64
MIDDLEBURY = Path(__file__).resolve().parents[3] / "shared" / "data" / "middlebury"
TEX = ConstantTexture(0.5)


def rays(n=500, seed=0, origin_z=175.6):
    gen = torch.Generator().manual_seed(seed)
    xy = (torch.rand(n, 2, generator=gen, dtype=F64) - 0.5) * 30.0
    o = torch.cat([xy, torch.full((n, 1), origin_z, dtype=F64)], 1)
    d = torch.cat([(torch.rand(n, 2, generator=gen, dtype=F64) - 0.5) * 0.2, torch.ones(n, 1, dtype=F64)], 1)
    return o, d / d.norm(dim=-1, keepdim=True)


def test_fronto_plane_hits_have_exact_depth():
    o, d = rays()
    hit = Plane((0.0, 0.0, 523.7), (0.0, 0.0, 1.0), TEX).intersect(o, d)
    assert torch.equal(hit.points[:, 2], torch.full((500,), 523.7, dtype=F64))
    torch.testing.assert_close(hit.points, o + hit.t[:, None] * d)


def test_slanted_plane_intersection_and_coords():
    o, d = rays()
    normal = torch.tensor([0.3, -0.2, 1.0], dtype=F64)
    plane = Plane((1.0, 2.0, 600.0), normal.tolist(), TEX)
    hit = plane.intersect(o, d)
    n = normal / normal.norm()
    assert ((hit.points - torch.tensor([1.0, 2.0, 600.0], dtype=F64)) @ n).abs().max() < 1e-9
    # coordinates are an isometry of the plane
    dist3 = (hit.points[0] - hit.points[1]).norm()
    torch.testing.assert_close((hit.coords[0] - hit.coords[1]).norm(), dist3)


def test_plane_bounds_and_backfacing():
    o, d = rays()
    plane = Plane((0.0, 0.0, 600.0), (0.0, 0.0, 1.0), TEX, bounds_mm=(-math.inf, 0.0, -math.inf, math.inf))
    hit = plane.intersect(o, d)
    hits = torch.isfinite(hit.t)
    assert torch.equal(hits, hit.points[:, 0] <= 0)
    behind = Plane((0.0, 0.0, 100.0), (0.0, 0.0, 1.0), TEX).intersect(o, d)
    assert torch.isinf(behind.t).all()
    with pytest.raises(SceneError, match="bounds_mm"):
        Plane((0, 0, 1), (0, 0, 1), TEX, bounds_mm=(1.0, 0.0, 0.0, 1.0))
    with pytest.raises(SceneError, match="normal must be non-zero"):
        Plane((0, 0, 1), (0, 0, 0), TEX)
    with pytest.raises(SceneError, match="texture must have"):
        Plane((0, 0, 1), (0, 0, 1), "wood")


def test_sphere_intersection():
    o, d = rays()
    ball = Sphere((0.0, 0.0, 500.0), 20.0, TEX)
    hit = ball.intersect(o, d)
    hits = torch.isfinite(hit.t)
    assert hits.any() and (~hits).any()
    torch.testing.assert_close((hit.points[hits] - torch.tensor([0, 0, 500.0], dtype=F64)).norm(dim=-1),
                               torch.full((int(hits.sum()),), 20.0, dtype=F64))
    assert (hit.points[hits, 2] <= 500.0).all()  # the near side
    # independent: distance of the ray line to the centre decides the hit
    rel = torch.tensor([0, 0, 500.0], dtype=F64) - o
    miss_dist = (rel - (rel * d).sum(-1, keepdim=True) * d).norm(dim=-1)
    assert torch.equal(hits, miss_dist <= 20.0)
    with pytest.raises(SceneError, match="radius_mm must be positive"):
        Sphere((0, 0, 500), 0.0, TEX)


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


def test_scene_nearest_hit_and_shading():
    near = Plane((0, 0, 400.0), (0, 0, 1), ConstantTexture(0.2), bounds_mm=(-math.inf, 0.0, -math.inf, math.inf))
    far = Plane((0, 0, 600.0), (0, 0, 1), ConstantTexture(0.8))
    scene = Scene([near, far], background=0.1)
    o, d = rays()
    hit, index = scene.intersect(o, d)
    expect_near = (o[:, 0] + (400.0 - o[:, 2]) * d[:, 0] / d[:, 2]) <= 0
    assert torch.equal(index == 0, expect_near) and torch.equal(index == 1, ~expect_near)
    shade = scene.shade(hit, index, 1)[:, 0]
    assert torch.equal(shade, torch.where(expect_near, 0.2, 0.8).to(torch.float32))
    up = torch.tensor([[0.0, 0.0, 100.0]], dtype=F64), torch.tensor([[0.0, 0.0, -1.0]], dtype=F64)
    hit, index = scene.intersect(*up)
    assert index.tolist() == [-1] and scene.shade(hit, index, 3)[0].tolist() == pytest.approx([0.1] * 3)


def test_scene_validation_against_the_prism():
    rig = thesis_setup1()
    with pytest.raises(SceneError, match="not beyond the prism's back plane at 175.6 mm"):
        fronto_parallel_plane(rig, 150.0).validate(rig)
    with pytest.raises(SceneError, match="not beyond the prism's back plane"):
        sphere_scene(rig, 200.0, 30.0, 400.0).validate(rig)
    fronto_parallel_plane(rig, 200.0).validate(rig)
    with pytest.raises(SceneError, match="at least one Surface"):
        Scene([])


@pytest.mark.parametrize(
    "make,match",
    [
        (lambda r: fronto_parallel_plane(r, -500.0), "depth_mm must be a positive depth"),
        (lambda r: fronto_parallel_plane(r, float("nan")), "depth_mm must be a positive depth"),
        (lambda r: step_scene(r, 600.0, 400.0), "near_mm must be smaller"),
        (lambda r: step_scene(r, 400.0, 600.0, near_side="top"), "Unknown near_side 'top'"),
        (lambda r: sphere_scene(r, 500.0, 50.0, 520.0), "in front of the background"),
        (lambda r: slanted_plane(r, 500.0, slant_deg=85.0), "within \\+-80 degrees"),
        (lambda r: height_field_scene(torch.ones(4, 4) * 500, torch.zeros(1, 0, 4), 10.0), "same \\(h, w\\)"),
        (lambda r: height_field_scene(torch.ones(0, 4), torch.zeros(0, 4), 10.0), "non-empty"),
        (lambda r: middlebury_scene("/nonexistent"), "must hold img_left.png"),
        (lambda r: disparity_scene(torch.rand(4, 4), torch.full((4, 4), float("nan"))), "no usable values"),
        (lambda r: disparity_scene(torch.rand(4, 5), torch.rand(4, 4)), "picture's size"),
        (lambda r: disparity_scene([[0.5]], torch.rand(4, 4)), "must be tensors"),
        (lambda r: disparity_scene(torch.rand(4, 4), torch.rand(4, 4), 700.0, 450.0), "near_mm must be smaller"),
    ],
)
def test_factory_errors(make, match):
    with pytest.raises(SceneError, match=match):
        make(thesis_setup1())


def test_factories():
    rig = thesis_setup1()
    assert fronto_parallel_plane(rig, 525.0).surfaces[0].texture.feature_mm == pytest.approx(3 * 525 * 0.00465 / 25)
    slanted = slanted_plane(rig, 600.0, slant_deg=30.0).surfaces[0]
    torch.testing.assert_close(slanted.normal, torch.tensor([-0.5, 0.0, math.sqrt(3) / 2], dtype=F64))
    board = checkerboard_target((10.0, 0.0, 600.0), (0.0, 0.0, 0.0), rows=6, cols=8, square_mm=10.0).surfaces[0]
    # inner corners sit at multiples of the square size, the board is centred on centre_mm
    torch.testing.assert_close(board.point, torch.tensor([-30.0, -30.0, 600.0], dtype=F64))
    assert board.bounds_mm == (-10.0, 90.0, -10.0, 70.0)
    assert circle_grid_target().channels == 1


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
