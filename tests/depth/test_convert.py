import pytest
import torch

from prismstereo import RigError, ShapeError, thesis_setup1, thesis_setup2
from prismstereo.depth import depth_to_disparity, depth_to_index, disparity_to_depth, index_to_depth
from prismstereo.epipolar import depth_hypotheses
from prismstereo.geometry import points_at_depth, project_points, trace_pixels

F64 = torch.float64


def test_index_depth_round_trip(dtype):
    depths = depth_hypotheses(228.0, 1374.0, 33, dtype=dtype)
    idx = torch.linspace(0, 32, 97, dtype=dtype)
    z = index_to_depth(idx, depths)
    torch.testing.assert_close(z[::3], depths)  # exact at integer indices
    torch.testing.assert_close(depth_to_index(z, depths), idx, atol=1e-4 if dtype == torch.float32 else 1e-9, rtol=0)
    # uniform in inverse depth: 1/Z is linear in the index
    inv = 1 / index_to_depth(torch.tensor([0.0, 0.25, 1.0], dtype=F64), depth_hypotheses(200.0, 400.0, 2))
    torch.testing.assert_close(inv[1], 0.75 * inv[0] + 0.25 * inv[2])


def test_index_to_depth_gradient():
    depths = depth_hypotheses(250.0, 1000.0, 8)
    idx = torch.tensor([1.3, 4.7], dtype=F64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda i: index_to_depth(i, depths), (idx,))
    with pytest.raises(RigError, match="at least 2 depth hypotheses"):
        index_to_depth(idx, torch.tensor([500.0], dtype=F64))
    with pytest.raises(ShapeError, match="depths must have shape"):
        depth_to_index(idx, torch.ones(2, 2, dtype=F64))


@pytest.mark.parametrize("make", [thesis_setup1, thesis_setup2])
def test_disparity_depth_round_trip_is_exact(make):
    rig = make()
    gen = torch.Generator().manual_seed(0)
    scale = torch.tensor([rig.apex_column - 1, rig.image_height - 1], dtype=F64)
    uv = torch.rand(500, 2, generator=gen, dtype=F64) * scale
    z = 228 + torch.rand(500, generator=gen, dtype=F64) * (1374 - 228)
    d = depth_to_disparity(rig, uv, z)
    ok = ~torch.isnan(d)
    assert ok.float().mean() > 0.6
    back = disparity_to_depth(rig, uv, d)
    assert ((back - z)[ok] / z[ok]).abs().max() < 1e-9
    assert torch.isnan(back[~ok]).all()
    # independent: disparity is the horizontal distance to the exact projection
    rays = trace_pixels(rig, uv[ok])
    proj = project_points(rig, points_at_depth(rays, z[ok]), "right")
    torch.testing.assert_close(d[ok], proj.uv[:, 0] - uv[ok, 0])


def test_disparity_to_depth_gradient():
    rig = thesis_setup1()
    uv = torch.tensor([[300.0, 200.0], [100.0, 600.0]], dtype=F64)
    d = depth_to_disparity(rig, uv, torch.tensor([400.0, 900.0], dtype=F64)).clone().requires_grad_(True)
    assert torch.autograd.gradcheck(lambda x: disparity_to_depth(rig, uv, x), (d,))
    p = rig.parameters(dtype=F64, requires_grad=True)
    disparity_to_depth(p, uv, d.detach()).sum().backward()
    assert p.alpha.grad.abs() > 0 and p.n.grad.abs() > 0
    with pytest.raises(RigError, match="z_range_mm"):
        disparity_to_depth(rig, uv, d.detach(), z_range_mm=(500.0, 300.0))
