import math

import pytest
import torch

from prismstereo import thesis_setup1
from prismstereo.synthetic import (
    ConstantTexture,
    Plane,
    Scene,
    SceneError,
    Sphere,
    checkerboard_target,
    circle_grid_target,
    fronto_parallel_plane,
    slanted_plane,
    sphere_scene,
    step_scene,
)

F64 = torch.float64
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
