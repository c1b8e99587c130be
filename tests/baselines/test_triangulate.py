import numpy as np
import pytest
import torch

from prismstereo import PrismStereoError, ShapeError
from prismstereo.baselines import (
    PinholePair,
    Triangulation,
    pinhole_from_opencv,
    pinhole_rays,
    project_pinhole,
    triangulate_exact,
    triangulate_pinholes,
)
from prismstereo.geometry import project_points
from prismstereo.synthetic import ImageFormation, fronto_parallel_plane, render
from tests.baselines.conftest import RIG

pytestmark = pytest.mark.usefixtures("one_thread")

F64 = torch.float64


def distorted_pair() -> PinholePair:
    """Two convergent distorted pinholes 18 mm apart (a bi-prism's virtual cameras, roughly)."""
    k = np.array([[1300.0, 0, 128], [0, 1290.0, 96], [0, 0, 1]])
    left = pinhole_from_opencv(k, np.array([0.3, -8.0, 0.002, -0.003, 0.0]), np.array([0.0, -0.054, 0.0]),
                               np.array([9.2, 0.0, -1.0]))
    right = pinhole_from_opencv(k * np.array([[1.01], [1.0], [1.0]]), np.array([-0.2, 5.0, -0.001, 0.002, 0.0]),
                                np.array([0.001, 0.054, 0.0]), np.array([-9.2, 0.1, -1.0]))
    return PinholePair(left, right)


def test_triangulate_pinholes_exact_on_consistent_pair():
    pair = distorted_pair()
    g = torch.Generator().manual_seed(0)
    pts = torch.rand(200, 3, generator=g, dtype=F64) * torch.tensor([40.0, 30.0, 1100.0]) \
        + torch.tensor([-20.0, -15.0, 250.0])
    out = triangulate_pinholes(pair, project_pinhole(pair.left, pts), project_pinhole(pair.right, pts))
    assert isinstance(out, Triangulation) and out.points.shape == (200, 3) and bool(out.valid.all())
    torch.testing.assert_close(out.points, pts, rtol=1e-9, atol=1e-8)
    assert float(out.gap_mm.max()) < 1e-8


def test_pinhole_rays_unit_and_axis():
    cam = distorted_pair().left
    origins, directions = pinhole_rays(cam, torch.tensor([[128.0, 96.0], [10.0, 180.0]], dtype=F64))
    torch.testing.assert_close(directions.norm(dim=1), torch.ones(2, dtype=F64))
    torch.testing.assert_close(directions[0], cam.rotation[:, 2])  # the principal point's ray is the axis
    torch.testing.assert_close(origins, cam.centre.expand(2, 3))


def test_pinhole_rays_errors():
    with pytest.raises(ShapeError, match=r"uv must have shape \(N, 2\)"):
        pinhole_rays(distorted_pair().left, torch.zeros(2, 3, dtype=F64))
    with pytest.raises(PrismStereoError, match="floating-point"):
        pinhole_rays(distorted_pair().left, torch.zeros(2, 2, dtype=torch.int64))


def test_triangulate_pinholes_diverging_rays_invalid():
    k = np.array([[100.0, 0, 50], [0, 100.0, 40], [0, 0, 1]])
    pair = PinholePair(pinhole_from_opencv(k, None, np.zeros(3), np.array([10.0, 0, 0])),
                       pinhole_from_opencv(k, None, np.zeros(3), np.array([-10.0, 0, 0])))
    out = triangulate_pinholes(pair, torch.tensor([[40.0, 40.0]]), torch.tensor([[60.0, 40.0]]))
    assert not bool(out.valid[0]) and float(out.depth[0]) < 0


def test_triangulate_exact_true_matches():
    """Exact optics + the renderer's true correspondences (Capture.match_uv) give the true depth (< 1e-6)."""
    cap = render(RIG, fronto_parallel_plane(RIG, 600.0, seed=1), ImageFormation(supersample=1, bits=None))
    v, u = cap.covisible[0, 0].nonzero().unbind(1)
    uv_left = torch.stack([u, v], dim=1).to(F64)
    out = triangulate_exact(RIG, uv_left, cap.match_uv[0, :, v, u].T)
    assert out.depth.shape == (u.numel(),) and u.numel() > 1000 and bool(out.valid.all())
    rel = (out.depth - cap.depth[0, 0, v, u]).abs() / cap.depth[0, 0, v, u]
    assert float(rel.max()) < 1e-6
    assert float(out.gap_mm.max()) < 1e-6


def test_triangulate_exact_wrong_halves_invalid():
    x = torch.tensor([[5.0, -3.0, 600.0], [-8.0, 4.0, 400.0]], dtype=F64)
    uv_l, uv_r = project_points(RIG, x, "left").uv, project_points(RIG, x, "right").uv
    assert bool(triangulate_exact(RIG, uv_l, uv_r).valid.all())
    assert not bool(triangulate_exact(RIG, uv_r, uv_l).valid.any())


@pytest.mark.parametrize("fn", ["pinholes", "exact"])
def test_triangulate_shape_errors(fn):
    call = (lambda a, b: triangulate_exact(RIG, a, b)) if fn == "exact" else \
        (lambda a, b: triangulate_pinholes(distorted_pair(), a, b))
    with pytest.raises(ShapeError, match="must have the same shape"):
        call(torch.zeros(3, 2), torch.zeros(4, 2))
    with pytest.raises(ShapeError, match=r"uv_left must have shape \(N, 2\)"):
        call(torch.zeros(3, 3), torch.zeros(3, 2))
    with pytest.raises(PrismStereoError, match="floating-point"):
        call(torch.zeros(3, 2, dtype=torch.int64), torch.zeros(3, 2))
