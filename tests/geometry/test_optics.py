import math

import numpy as np
import onnxruntime as ort
import pytest
import torch
from kornia.geometry.camera import PinholeCamera

from prismstereo import BiPrismRig, OptionError, PrismStereoError, RigError, ShapeError, thesis_setup1, thesis_setup2
from prismstereo.geometry import (
    apex_ray,
    half_of_pixels,
    pixel_directions,
    points_at_depth,
    project_points,
    trace_directions,
    trace_pixels,
)
from tests.conftest import random_pixels

F64 = torch.float64


# ----------------------------------------------------------------------------- independent reference
def reference_trace(rig: BiPrismRig, uv: torch.Tensor):
    """Untilted prism, by the thesis' closed forms: entry point of eq. 3.4 (generalised to an offset d) and
    refraction by conservation of the tangential direction component (n_1 t_1 = n_2 t_2), not the vector
    Snell formula under test. Returns (origins, directions, entry points, inside directions)."""
    n, ta, d = rig.refractive_index, math.tan(rig.alpha_rad), rig.prism_offset_x_mm
    x = (uv[..., 0] - rig.cx) * rig.pixel_size_mm
    y = (uv[..., 1] - rig.cy) * rig.pixel_size_mm
    f = rig.focal_length_mm
    s = (uv[..., 0] >= rig.apex_column).to(uv.dtype) * 2 - 1  # face z = T_o + s (x - d) tan(alpha)
    g = (rig.apex_distance_mm - s * d * ta) / (f - s * x * ta)  # eq. 3.4 with the offset
    p1 = torch.stack([g * x, g * y, g * f], dim=-1)
    ray = p1 / p1.norm(dim=-1, keepdim=True)
    m = torch.stack([-s * ta, torch.zeros_like(s), torch.ones_like(s)], dim=-1)
    m = m / m.norm(dim=-1, keepdim=True)  # face normal pointing into the glass
    tangential = ray - (ray * m).sum(-1, keepdim=True) * m
    t_in = tangential / n
    d1 = t_in + torch.sqrt(1 - t_in.square().sum(-1, keepdim=True)) * m
    back = rig.apex_distance_mm + rig.prism_thickness_mm
    p2 = p1 + d1 * ((back - p1[..., 2:]) / d1[..., 2:])
    xy = n * d1[..., :2]
    d2 = torch.cat([xy, torch.sqrt((1 - xy.square().sum(-1, keepdim=True)).clamp_min(0))], dim=-1)
    return p2, d2, p1, d1


@pytest.mark.parametrize("make", [thesis_setup1, thesis_setup2, lambda: thesis_setup1().replace(prism_offset_x_mm=3.0)])
def test_trace_matches_closed_form_reference(make):
    rig = make()
    uv = random_pixels(rig, 4000, F64)
    uv = uv[(uv[:, 0] - rig.apex_column).abs() > 1e-6]
    rays = trace_pixels(rig, uv)
    p2, d2, p1, _ = reference_trace(rig, uv)
    v = rays.valid
    assert v.float().mean() > 0.8
    torch.testing.assert_close(rays.entries, p1, atol=1e-10, rtol=0)
    torch.testing.assert_close(rays.origins[v], p2[v], atol=1e-10, rtol=0)
    torch.testing.assert_close(rays.directions[v], d2[v], atol=1e-12, rtol=0)
    assert torch.equal(rays.left, uv[:, 0] < rig.apex_column)


# ----------------------------------------------------------------------------- pixel directions
def test_pixel_directions_match_kornia(dtype):
    rig = thesis_setup1().replace(principal_point=(500.0, 370.0))
    uv = random_pixels(rig, 100, dtype)
    ours = pixel_directions(rig, uv)
    fpx = rig.focal_length_px
    k = torch.tensor([[fpx, 0, 500.0, 0], [0, fpx, 370.0, 0], [0, 0, 1, 0], [0, 0, 0, 1]], dtype=dtype)
    cam = PinholeCamera(k[None], torch.eye(4, dtype=dtype)[None], torch.tensor([768.0]), torch.tensor([1024.0]))
    theirs = cam.unproject(uv, torch.ones(100, 1, dtype=dtype))
    theirs = theirs / theirs.norm(dim=-1, keepdim=True)
    torch.testing.assert_close(ours, theirs)
    torch.testing.assert_close(
        pixel_directions(rig, torch.tensor([500.0, 370.0], dtype=dtype)), torch.tensor([0.0, 0.0, 1.0], dtype=dtype)
    )


# ----------------------------------------------------------------------------- trace
def test_trace_shapes_and_dtype(rig, dtype):
    uv = random_pixels(rig, 24, dtype).reshape(2, 3, 4, 2)
    rays = trace_pixels(rig, uv)
    assert rays.origins.shape == (2, 3, 4, 3) and rays.directions.shape == (2, 3, 4, 3)
    assert rays.valid.shape == (2, 3, 4) and rays.left.shape == (2, 3, 4) and rays.entries.shape == (2, 3, 4, 3)
    assert rays.origins.dtype == dtype and rays.valid.dtype == torch.bool
    single = trace_pixels(rig, uv[0, 0, 0])
    assert single.origins.shape == (3,) and single.valid.shape == ()


def test_trace_halves_follow_apex_column():
    for rig in (thesis_setup1(), thesis_setup1().replace(prism_offset_x_mm=-2.0)):
        uv = random_pixels(rig, 2000, F64)
        assert torch.equal(half_of_pixels(rig, uv), uv[:, 0] < rig.apex_column)


def test_trace_exits_on_back_plane_with_unit_directions(rig):
    uv = random_pixels(rig, 500, F64)
    rays = trace_pixels(rig, uv)
    torch.testing.assert_close(rays.directions.norm(dim=-1), torch.ones(500, dtype=F64))
    if rig.prism_tilt_deg == (0.0, 0.0, 0.0):
        back = rig.apex_distance_mm + rig.prism_thickness_mm
        torch.testing.assert_close(rays.origins[:, 2], torch.full((500,), back, dtype=F64))


def test_trace_forced_half_flags_wrong_face():
    rig = thesis_setup1()
    uv = torch.tensor([[100.0, 300.0], [900.0, 300.0]], dtype=F64)
    assert trace_pixels(rig, uv, half="left").valid.tolist() == [True, False]
    assert trace_pixels(rig, uv, half="right").valid.tolist() == [False, True]
    d = pixel_directions(rig, uv)
    assert trace_directions(rig, d).left.tolist() == [True, False]


def test_trace_bad_arguments():
    rig = thesis_setup1()
    with pytest.raises(ShapeError, match=r"uv must have shape \(\*, 2\)"):
        trace_pixels(rig, torch.zeros(4, 3))
    with pytest.raises(PrismStereoError, match="floating-point"):
        trace_pixels(rig, torch.zeros(4, 2, dtype=torch.int64))
    with pytest.raises(OptionError, match="Unknown half 'centre'. Choose from: 'auto', 'left', 'right'"):
        trace_pixels(rig, torch.zeros(4, 2), half="centre")
    with pytest.raises(RigError, match="rig must be a BiPrismRig or RigParameters"):
        trace_pixels({"alpha_deg": 6.4}, torch.zeros(4, 2))
    with pytest.raises(ShapeError, match="directions must have shape"):
        trace_directions(rig, torch.zeros(2, 2))


# ----------------------------------------------------------------------------- central ray: eq. 5.2-5.5, 5.27-5.33
def phi2(alpha: float, n: float) -> float:
    """Thesis eq. 5.5."""
    return math.asin(n * math.sin(alpha - math.asin(math.sin(alpha) / n)))


@pytest.mark.parametrize("make,expected", [(thesis_setup1, 0.05376), (thesis_setup2, 0.18834)])
def test_apex_ray_angle_is_phi2(make, expected):
    rig = make()
    for half, sign in (("left", 1.0), ("right", -1.0)):
        ray = apex_ray(rig, half)
        beta = math.atan2(ray.directions[0].item(), ray.directions[2].item())
        assert beta == pytest.approx(sign * phi2(rig.alpha_rad, rig.refractive_index), abs=1e-12)
        assert round(sign * beta, 5) == expected  # thesis Table 5.3
        assert bool(ray.valid)


@pytest.mark.parametrize("d", [-4.0, 2.5, 6.0])
def test_apex_ray_with_offset_follows_eq_5_27_to_5_33(d):
    rig = thesis_setup1().replace(prism_offset_x_mm=d)
    a, n, t, t_o = rig.alpha_rad, rig.refractive_index, rig.prism_thickness_mm, rig.apex_distance_mm
    w0 = math.atan(d / t_o)  # eq. 5.27
    mu1, mu2 = a - w0, a + w0  # eq. 5.28-5.29
    mu3p = a - math.asin(math.sin(mu1) / n)  # eq. 5.30
    mu4p = math.asin(math.sin(mu2) / n) - a  # eq. 5.31
    # The thesis names halves after its mirrored image: its mu_3 / h_r ray is our left half's.
    expected = {"left": (math.asin(n * math.sin(mu3p)), d + t * math.tan(mu3p)),  # eq. 5.33 (h_r)
                "right": (math.asin(n * math.sin(mu4p)), d + t * math.tan(mu4p))}  # eq. 5.32 (h_l)
    for half, (beta, h) in expected.items():
        ray = apex_ray(rig, half)
        assert math.atan2(ray.directions[0].item(), ray.directions[2].item()) == pytest.approx(beta, abs=1e-12)
        assert ray.origins[0].item() == pytest.approx(h, abs=1e-10)


def test_thin_prism_limit():
    # deviation -> (n - 1) alpha as alpha -> 0 (relative error O(alpha^2))
    for alpha_deg in (0.5, 0.05, 0.005):
        rig = thesis_setup1().replace(alpha_deg=alpha_deg)
        a = rig.alpha_rad
        uv = torch.tensor([[500.0, 383.5], [505.0, 380.0], [520.0, 390.0], [530.0, 383.5]], dtype=F64)
        incoming = pixel_directions(rig, uv)
        rays = trace_pixels(rig, uv)
        deviation = torch.acos((incoming * rays.directions).sum(-1).clamp(max=1.0))
        rel = (deviation / ((rig.refractive_index - 1) * a) - 1).abs().max().item()
        assert rel < 2e-3 * max(alpha_deg, 0.05)


# ----------------------------------------------------------------------------- validity masks
def test_total_internal_reflection_mask():
    rig = thesis_setup2().replace(alpha_deg=55.0, refractive_index=2.0, prism_thickness_mm=300.0)
    uv = random_pixels(rig, 3000, F64)
    uv = uv[(uv[:, 0] - rig.apex_column).abs() > 0.5]
    rays = trace_pixels(rig, uv)
    _, _, p1, d1 = reference_trace(rig, uv)
    tir = rig.refractive_index * d1[:, :2].norm(dim=-1) > 1  # critical angle at the back plane
    within = (p1[:, 0] - rig.prism_offset_x_mm).abs() < rig.prism_thickness_mm / math.tan(rig.alpha_rad)
    assert tir.any() and (~tir & within).any()
    assert torch.equal(rays.valid, ~tir & within)
    assert torch.isfinite(rays.directions).all()


def test_miss_mask_narrow_prism():
    rig = thesis_setup1().replace(prism_thickness_mm=0.5)  # back plane 8.9 mm wide
    uv = random_pixels(rig, 3000, F64)
    rays = trace_pixels(rig, uv)
    _, _, p1, _ = reference_trace(rig, uv)
    half_width = rig.prism_thickness_mm / math.tan(rig.alpha_rad)
    margin = (p1[:, 0].abs() - half_width).abs() > 1e-9
    inside = p1[:, 0].abs() <= half_width
    assert inside.any() and (~inside).any()
    assert torch.equal(rays.valid[margin], inside[margin])


def test_ray_leaving_through_other_face_is_invalid():
    # a steep prism: rays entering near the apex cross under it and hit the other face from inside
    rig = thesis_setup1().replace(alpha_deg=80.0, refractive_index=1.5, prism_thickness_mm=50.0)
    u = torch.linspace(300.0, 723.0, 424, dtype=F64)
    uv = torch.stack([u, torch.full_like(u, 383.5)], dim=-1)
    uv = uv[(uv[:, 0] - rig.apex_column).abs() > 1e-3]
    rays = trace_pixels(rig, uv)
    _, _, p1, d1 = reference_trace(rig, uv)
    ta, t_o = math.tan(rig.alpha_rad), rig.apex_distance_mm
    back = t_o + rig.prism_thickness_mm
    s_other = torch.where(p1[:, 0] < 0, 1.0, -1.0).to(F64)  # the other face: z = T_o + s x tan(alpha)
    t = (t_o + s_other * p1[:, 0] * ta - p1[:, 2]) / (d1[:, 2] - s_other * d1[:, 0] * ta)
    hit = p1 + t.unsqueeze(-1) * d1
    hits_other = (t > 1e-9) & (hit[:, 2] < back) & (torch.sign(hit[:, 0]) == s_other)
    within = p1[:, 0].abs() <= rig.prism_thickness_mm / ta
    tir = rig.refractive_index * d1[:, :2].norm(dim=-1) > 1
    assert hits_other.any() and (~hits_other & within & ~tir).any()
    assert torch.equal(rays.valid, ~hits_other & within & ~tir)


# ----------------------------------------------------------------------------- points at depth
def test_points_at_depth():
    rig = thesis_setup1()
    rays = trace_pixels(rig, random_pixels(rig, 50, F64))
    pts = points_at_depth(rays, 700.0)
    assert pts.shape == (50, 3)
    assert torch.equal(pts[:, 2], torch.full((50,), 700.0, dtype=F64))
    rel = pts - rays.origins
    cross = torch.linalg.cross(rel, rays.directions)
    assert cross.norm(dim=-1).max() < 1e-9


# ----------------------------------------------------------------------------- gradients
PARAM_NAMES = ("alpha", "n", "f", "T", "T_o", "d", "tilt")


def params_fn(rig, fn):
    """A gradcheck function of the rig parameters PARAM_NAMES (float64) and its inputs."""
    base = rig.parameters(dtype=F64)

    def wrapped(*values):
        p = base._replace(**dict(zip(PARAM_NAMES, values, strict=True)))
        return fn(p)

    inputs = tuple(getattr(base, k).clone().requires_grad_(True) for k in PARAM_NAMES)
    return wrapped, inputs


def misaligned_rig():
    """Setup 1 with the prism offset and tilted about all three axes."""
    return thesis_setup1().replace(prism_offset_x_mm=1.0, prism_tilt_deg=(0.5, -0.5, 0.3))


@pytest.mark.parametrize("make", [thesis_setup1, misaligned_rig])
def test_gradcheck_trace_wrt_rig(make):
    rig = make()
    uv = torch.tensor([[100.0, 200.0], [700.0, 600.0], [480.0, 390.0]], dtype=F64)
    fn, inputs = params_fn(rig, lambda p: torch.cat(list(trace_pixels(p, uv)[:2]), -1))
    assert torch.autograd.gradcheck(fn, inputs)


def test_large_batches_trace_bit_for_bit_as_small_ones():
    """Large eager batches take a faster dot product than small ones: the same floats, signed zeros included."""
    rig = thesis_setup1().replace(prism_offset_x_mm=-1.5, prism_tilt_deg=(1.0, -2.0, 0.5))
    uv = torch.cat([random_pixels(rig, 20_000, F64, seed=3), torch.tensor([[rig.cx, rig.cy]] * 8, dtype=F64)])
    big = trace_pixels(rig, uv)
    small = [trace_pixels(rig, chunk) for chunk in uv.split(1000)]
    for field in ("origins", "directions", "entries", "valid", "left"):
        whole, parts = getattr(big, field), torch.cat([getattr(part, field) for part in small])
        assert torch.equal(whole.view(torch.int64) if whole.is_floating_point() else whole,
                           parts.view(torch.int64) if parts.is_floating_point() else parts), field


def test_gradcheck_trace_wrt_pixels():
    rig = thesis_setup1()
    uv = torch.tensor([[100.0, 200.0], [700.0, 600.0]], dtype=F64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda x: torch.cat(list(trace_pixels(rig, x)[:2]), -1), (uv,))


def test_gradients_finite_on_invalid_rays():
    rig = thesis_setup2().replace(alpha_deg=55.0, refractive_index=2.0, prism_thickness_mm=300.0)
    p = rig.parameters(dtype=F64, requires_grad=True)
    rays = trace_pixels(p, random_pixels(rig, 500, F64))
    assert not rays.valid.all()
    (rays.origins.sum() + rays.directions.sum()).backward()
    assert all(torch.isfinite(t.grad).all() for t in p if isinstance(t, torch.Tensor))


# ----------------------------------------------------------------------------- ONNX
class _Optics(torch.nn.Module):
    def __init__(self, rig: BiPrismRig) -> None:
        super().__init__()
        self.p = rig.parameters(dtype=torch.float32)

    def forward(self, uv: torch.Tensor, points: torch.Tensor):
        rays = trace_pixels(self.p, uv)
        # 2 Newton iterations (+ the final step) already converge here in float32 (every point valid, as checked
        # below); the default 5 only repeat the same unrolled step, making the graph and its export 2.5x larger
        proj = project_points(self.p, points, "left", iterations=2)
        return rays.origins, rays.directions, proj.uv, proj.valid


@pytest.mark.parametrize("distortion", [(0.0,) * 5, (-0.08, 0.02, 5e-4, -5e-4, 0.0)], ids=["pinhole", "distorted"])
def test_onnx_export_matches_torch(tmp_path, distortion):
    rig = thesis_setup1().replace(prism_offset_x_mm=0.5, distortion=distortion)
    model = _Optics(rig)
    uv = random_pixels(rig, 64, torch.float32)
    pts = points_at_depth(trace_pixels(rig, uv[:32] * torch.tensor([0.45, 1.0])), 700.0)
    path = tmp_path / "optics.onnx"
    with pytest.warns(Warning):  # the legacy exporter warns about deprecation and traced checks
        torch.onnx.export(model, (uv, pts), str(path), dynamo=False, opset_version=17,
                          input_names=["uv", "points"], output_names=["origins", "directions", "uv_out", "valid"])
    session = ort.InferenceSession(str(path))
    out = session.run(None, {"uv": uv.numpy(), "points": pts.numpy()})
    ref = [t.detach().numpy() for t in model(uv, pts)]
    np.testing.assert_allclose(out[0], ref[0], atol=1e-4)
    np.testing.assert_allclose(out[1], ref[1], atol=1e-6)
    np.testing.assert_allclose(out[2], ref[2], atol=2e-3)
    assert (out[3] == ref[3]).all() and ref[3].all()
