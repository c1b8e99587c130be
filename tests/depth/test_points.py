import numpy as np
import pytest
import torch

from prismstereo import ShapeError, thesis_setup1
from prismstereo.depth import PointCloudError, depth_to_points, read_ply, write_ply
from prismstereo.geometry import project_points
from tests.conftest import ROUND_TRIP_TOL, tilted_rig

F64 = torch.float64


pytestmark = pytest.mark.usefixtures("one_thread")


def _random_depth(rig, dtype, batch=2, seed=0):
    gen = torch.Generator().manual_seed(seed)
    depth = 250.0 + 1000.0 * torch.rand(batch, 1, rig.image_height, rig.reference_width, generator=gen, dtype=F64)
    return depth.to(dtype)


@pytest.mark.parametrize("make", [lambda: thesis_setup1().downscaled(8), lambda: tilted_rig().downscaled(8)],
                         ids=["setup1", "tilted"])
def test_points_project_back_to_the_pixel_grid(make, dtype):
    rig = make()
    depth = _random_depth(rig, dtype)
    pts = depth_to_points(rig, depth)
    assert pts.shape == (2, 3, rig.image_height, rig.reference_width) and pts.dtype == dtype
    finite = torch.isfinite(pts).all(1)
    assert finite.float().mean() > 0.95  # only rays that miss the prism are NaN
    torch.testing.assert_close(pts[:, 2][finite], depth[:, 0][finite], rtol=0, atol=0)  # Z is the depth
    proj = project_points(rig, pts.permute(0, 2, 3, 1)[finite], "left")
    u = torch.arange(rig.reference_width, dtype=dtype)
    v = torch.arange(rig.image_height, dtype=dtype)
    grid = torch.stack(torch.meshgrid(u, v, indexing="xy"), -1).expand(2, -1, -1, -1)[finite]
    assert proj.valid.all()
    assert (proj.uv - grid).abs().max() < ROUND_TRIP_TOL[dtype]


def test_invalid_depth_gives_nan_points():
    rig = thesis_setup1().downscaled(8)
    depth = _random_depth(rig, F64, batch=1)
    depth[0, 0, 3, 4] = float("nan")
    depth[0, 0, 5, 6] = float("inf")
    valid = torch.ones_like(depth, dtype=torch.bool)
    valid[0, 0, 7, 8] = False
    pts = depth_to_points(rig, depth, valid)
    for v, u in ((3, 4), (5, 6), (7, 8)):
        assert torch.isnan(pts[0, :, v, u]).all()
    assert torch.isfinite(pts[0, :, 0, 0]).all()


def test_gradcheck_depth_and_rig():
    rig = thesis_setup1().downscaled(64)  # 16 x 12 sensor, 8 reference columns
    depth = _random_depth(rig, F64, batch=1).requires_grad_(True)
    assert torch.autograd.gradcheck(lambda d: depth_to_points(rig, d), (depth,))
    p = rig.parameters(dtype=F64)
    t_o = p.T_o.clone().requires_grad_(True)
    depth = depth.detach()
    assert torch.autograd.gradcheck(lambda t: depth_to_points(p._replace(T_o=t), depth), (t_o,))
    nan_depth = depth.clone().requires_grad_(True)
    with torch.no_grad():
        nan_depth[0, 0, 0, 0] = float("nan")
    depth_to_points(rig, nan_depth).nan_to_num(0.0).sum().backward()
    assert torch.isfinite(nan_depth.grad).all() and nan_depth.grad[0, 0, 0, 0] == 0


def test_depth_to_points_shape_errors():
    rig = thesis_setup1().downscaled(8)
    with pytest.raises(ShapeError, match=r"\(B, 1, 96, 64\) for this rig"):
        depth_to_points(rig, torch.ones(1, 1, 96, 128))
    with pytest.raises(ShapeError, match="depth must have shape"):
        depth_to_points(rig, torch.ones(96, 64))
    with pytest.raises(ShapeError, match="valid must have shape"):
        depth_to_points(rig, torch.ones(1, 1, 96, 64), torch.ones(96, 64, dtype=torch.bool))


def test_ply_round_trip_image_points(tmp_path):
    gen = torch.Generator().manual_seed(1)
    pts = torch.randn(3, 6, 5, generator=gen) * 100
    pts[:, 0, 0] = float("nan")
    valid = torch.ones(6, 5, dtype=torch.bool)
    valid[2, 3] = False
    grey = torch.rand(1, 6, 5, generator=gen)
    n = write_ply(tmp_path / "a.ply", pts, valid, grey)
    assert n == 28
    cloud = read_ply(tmp_path / "a.ply")
    keep = valid.clone()
    keep[0, 0] = False
    torch.testing.assert_close(cloud.points, pts.permute(1, 2, 0)[keep])
    expected = (grey[0][keep] * 255).round().to(torch.uint8)
    assert cloud.colors.dtype == torch.uint8 and (cloud.colors == expected[:, None]).all()
    header = (tmp_path / "a.ply").read_bytes().split(b"end_header\n")[0].decode()
    assert "format binary_little_endian 1.0" in header and "element vertex 28" in header
    assert "property float x" in header and "property uchar red" in header


def test_ply_round_trip_point_list(tmp_path):
    pts = torch.tensor([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]], dtype=F64)
    rgb = torch.tensor([[255, 0, 0], [0, 10, 20]], dtype=torch.uint8)
    assert write_ply(tmp_path / "b.ply", pts, colors=rgb) == 2
    cloud = read_ply(tmp_path / "b.ply")
    assert cloud.points.dtype == torch.float32 and cloud.points.tolist() == pts.tolist()
    assert cloud.colors.tolist() == rgb.tolist()
    assert write_ply(tmp_path / "c.ply", pts, valid=torch.tensor([False, True])) == 1
    cloud = read_ply(tmp_path / "c.ply")
    assert cloud.colors is None and cloud.confidence is None and cloud.points.tolist() == [[4.0, 5.0, 6.0]]


def test_ply_confidence_and_camera_to_world(tmp_path):
    """A confidence property laid out like the mask, and points moved by a rigid camera-to-world transform."""
    gen = torch.Generator().manual_seed(2)
    pts = torch.randn(3, 4, 5, generator=gen, dtype=F64) * 100
    valid = torch.rand(4, 5, generator=gen) > 0.3
    conf = torch.rand(1, 4, 5, generator=gen)
    angle = torch.tensor(0.3, dtype=F64)
    pose = torch.eye(4, dtype=F64)
    pose[:3, :3] = torch.tensor([[torch.cos(angle), -torch.sin(angle), 0.0], [torch.sin(angle), torch.cos(angle), 0.0],
                                 [0.0, 0.0, 1.0]], dtype=F64)
    pose[:3, 3] = torch.tensor([10.0, -20.0, 500.0], dtype=F64)
    n = write_ply(tmp_path / "w.ply", pts, valid, confidence=conf, camera_to_world=pose)
    cloud = read_ply(tmp_path / "w.ply")
    assert n == int(valid.sum()) and cloud.colors is None
    torch.testing.assert_close(cloud.confidence, conf[0][valid])
    camera = pts.permute(1, 2, 0)[valid]
    world = camera @ pose[:3, :3].T + pose[:3, 3]
    torch.testing.assert_close(cloud.points.double(), world, atol=1e-3, rtol=1e-6)
    assert b"world frame" in (tmp_path / "w.ply").read_bytes()[:200]
    with pytest.raises(ShapeError, match=r"confidence must have shape \(4, 5\)"):
        write_ply(tmp_path / "x.ply", pts, confidence=torch.ones(3, 5))
    with pytest.raises(ShapeError, match=r"camera_to_world must be a \(4, 4\) tensor"):
        write_ply(tmp_path / "x.ply", pts, camera_to_world=torch.eye(3))


def test_ply_errors(tmp_path):
    with pytest.raises(ShapeError, match="points must have shape"):
        write_ply(tmp_path / "x.ply", torch.ones(4, 2))
    with pytest.raises(ShapeError, match="valid must have shape"):
        write_ply(tmp_path / "x.ply", torch.ones(5, 3), valid=torch.ones(4, dtype=torch.bool))
    with pytest.raises(ShapeError, match="1 \\(grey\\) or 3 \\(RGB\\) channels"):
        write_ply(tmp_path / "x.ply", torch.ones(5, 3), colors=torch.ones(5, 2))
    with pytest.raises(PointCloudError, match="cannot read"):
        read_ply(tmp_path / "missing.ply")
    (tmp_path / "ascii.ply").write_text("ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nend_header\n1\n")
    with pytest.raises(PointCloudError, match="only binary_little_endian"):
        read_ply(tmp_path / "ascii.ply")
    write_ply(tmp_path / "t.ply", torch.ones(4, 3))
    data = (tmp_path / "t.ply").read_bytes()
    (tmp_path / "t.ply").write_bytes(data[:-5])
    with pytest.raises(PointCloudError, match="truncated"):
        read_ply(tmp_path / "t.ply")
    rows = np.zeros(1, dtype=[("x", "<f4")])
    (tmp_path / "nox.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 1\n"
                                       b"property float x\nend_header\n" + rows.tobytes())
    with pytest.raises(PointCloudError, match="no vertex element with x, y, z"):
        read_ply(tmp_path / "nox.ply")
