"""Thin-lens defocus and Fresnel transmission of the renderer (prismstereo.synthetic.lens)."""

import math

import pytest
import torch

from prismstereo import ShapeError, thesis_setup1, thesis_setup2
from prismstereo.geometry import apex_ray, trace_pixels
from prismstereo.geometry.surfaces import euler_rotation
from prismstereo.synthetic import (
    ConstantTexture,
    ImageFormation,
    NoiseTexture,
    Plane,
    Scene,
    SceneError,
    apparent_depth,
    blur_circle_px,
    defocus_blur,
    fresnel_transmittance,
    fronto_parallel_plane,
    prism_transmittance,
    render,
    render_radiance,
    step_scene,
)
from prismstereo.synthetic.lens import blur_levels, disk_kernel, fill_nearest
from tests.conftest import offset_rig, scaled_rig, tilted_rig

F64 = torch.float64
EXACT = ImageFormation(supersample=1, bits=None)


def pixel_grid(rig):
    v, u = torch.meshgrid(torch.arange(rig.image_height, dtype=F64), torch.arange(rig.image_width, dtype=F64),
                          indexing="ij")
    return torch.stack([u, v], dim=-1)


def gradient_energy(img, mask=None):
    """Mean squared forward difference (u and v) over ``mask`` (both pixels of a difference inside it)."""
    gu, gv = img[..., :, 1:] - img[..., :, :-1], img[..., 1:, :] - img[..., :-1, :]
    if mask is None:
        return (gu.pow(2).mean() + gv.pow(2).mean()).item()
    mu, mv = mask[..., :, 1:] & mask[..., :, :-1], mask[..., 1:, :] & mask[..., :-1, :]
    return (gu[mu].pow(2).mean() + gv[mv].pow(2).mean()).item()


# ----------------------------------------------------------------------------------- blur circle
def test_blur_circle_is_zero_at_focus_and_matches_hand_value(dtype):
    rig = thesis_setup1()
    c = blur_circle_px(rig, torch.tensor([600.0, 400.0], dtype=dtype), f_number=12.5, focus_mm=600.0)
    assert c.dtype == dtype
    # A = 25 / 12.5 = 2 mm; c = 2 * 25 * 200 / (400 * 575) = 0.0434783 mm = 9.35016 px of 4.65 um
    expected = torch.tensor([0.0, 2.0 * 25.0 * 200.0 / (400.0 * 575.0) / 0.00465], dtype=dtype)
    torch.testing.assert_close(c, expected)
    half = blur_circle_px(rig, torch.tensor([400.0], dtype=dtype), f_number=6.25, focus_mm=600.0)
    torch.testing.assert_close(half, 2.0 * expected[1:])  # half the f-number, twice the aperture


def test_blur_circle_grows_away_from_focus_and_keeps_shape():
    rig = thesis_setup1().downscaled(8)
    near = torch.linspace(200.0, 600.0, 41, dtype=F64)
    far = torch.linspace(600.0, 5000.0, 41, dtype=F64)
    c_near = blur_circle_px(rig, near, 8.0, 600.0)
    c_far = blur_circle_px(rig, far, 8.0, 600.0)
    assert (c_near.diff() < 0).all() and (c_far.diff() > 0).all()
    limit = blur_circle_px(rig, torch.tensor([math.inf], dtype=F64), 8.0, 600.0)  # A f / (Z_f - f)
    torch.testing.assert_close(limit, torch.tensor([25.0 / 8.0 * 25.0 / 575.0 / rig.pixel_size_mm], dtype=F64))
    depth = torch.full((2, 1, 3, 5), 450.0)
    depth[0, 0, 1, 1] = math.nan
    out = blur_circle_px(rig, depth, 4.0, 800.0)
    assert out.shape == depth.shape and torch.isnan(out[0, 0, 1, 1]) and torch.isfinite(out[1]).all()


@pytest.mark.parametrize(
    "kwargs,error,match",
    [({"f_number": 0.0}, SceneError, "f_number must be a finite number > 0"),
     ({"f_number": -2.0}, SceneError, "f_number must be a finite number > 0"),
     ({"f_number": math.nan}, SceneError, "f_number must be a finite number > 0"),
     ({"focus_mm": 25.0}, SceneError, "focus_mm must exceed the lens' focal length 25 mm"),
     ({"focus_mm": math.inf}, SceneError, "focus_mm must be a finite number"),
     ({"depth_mm": torch.tensor([400.0, -1.0])}, SceneError, "depth_mm must be positive"),
     ({"depth_mm": [400.0]}, ShapeError, "depth_mm must be a torch.Tensor"),
     ({"depth_mm": torch.tensor([400])}, TypeError, "depth_mm must be a floating-point tensor")],
)
def test_blur_circle_errors(kwargs, error, match):
    args = {"depth_mm": torch.tensor([400.0]), "f_number": 8.0, "focus_mm": 600.0} | kwargs
    with pytest.raises(error, match=match):
        blur_circle_px(thesis_setup1(), **args)


# ----------------------------------------------------------------------------------- Fresnel
def test_fresnel_normal_incidence(dtype):
    for n1, n2 in [(1.0, 1.5), (1.5, 1.0), (1.0, 1.48), (1.33, 1.9)]:
        t = fresnel_transmittance(torch.ones(3, dtype=dtype), n1, n2)
        assert t.dtype == dtype
        torch.testing.assert_close(t, torch.full_like(t, 1.0 - ((n1 - n2) / (n1 + n2)) ** 2))


def test_fresnel_matches_angle_form_and_is_reciprocal():
    theta_i = torch.linspace(0.01, 1.5, 50, dtype=F64)
    n1, n2 = 1.0, 1.5
    theta_t = torch.asin(n1 / n2 * torch.sin(theta_i))
    # independent textbook form: R_s = sin^2(i - t) / sin^2(i + t), R_p = tan^2(i - t) / tan^2(i + t)
    r_s = torch.sin(theta_i - theta_t) ** 2 / torch.sin(theta_i + theta_t) ** 2
    r_p = torch.tan(theta_i - theta_t) ** 2 / torch.tan(theta_i + theta_t) ** 2
    t = fresnel_transmittance(torch.cos(theta_i), n1, n2)
    torch.testing.assert_close(t, 1.0 - 0.5 * (r_s + r_p))
    # reciprocity: the same pair of angles transmits the same power in both directions
    torch.testing.assert_close(fresnel_transmittance(torch.cos(theta_t), n2, n1), t)
    # the normal's orientation does not matter
    torch.testing.assert_close(fresnel_transmittance(-torch.cos(theta_i), n1, n2), t)
    brewster = torch.atan(torch.tensor([n2 / n1], dtype=F64))  # R_p = 0 there
    t_b = fresnel_transmittance(torch.cos(brewster), n1, n2)
    t_t = torch.asin(n1 / n2 * torch.sin(brewster))
    torch.testing.assert_close(t_b, 1.0 - 0.5 * torch.sin(brewster - t_t) ** 2 / torch.sin(brewster + t_t) ** 2)


def test_fresnel_total_internal_reflection_and_grazing(dtype):
    n = 1.5
    critical = math.asin(1.0 / n)
    angles = torch.linspace(0.0, math.pi / 2, 2001, dtype=dtype)
    cos = torch.cos(angles)
    inner = fresnel_transmittance(cos, n, 1.0)
    outer = fresnel_transmittance(cos, 1.0, n)
    for t in (inner, outer):
        assert torch.isfinite(t).all() and (t >= 0).all() and (t <= 1).all()
    assert (inner[angles > critical + 1e-3] == 0).all()
    assert (inner[angles < critical - 1e-3] > 0).all()
    assert (outer[:-1] > 0).all() and (outer.diff() <= 1e-6).all()  # falls monotonically to 0 at grazing
    grazing = torch.tensor([0.0, 1e-12, -0.0], dtype=dtype)
    for n1, n2 in [(1.0, 1.5), (1.5, 1.0), (1.2, 1.2)]:
        g = fresnel_transmittance(grazing, n1, n2)
        assert torch.isfinite(g).all() and (g <= 1e-5).all()
    torch.testing.assert_close(fresnel_transmittance(torch.tensor([0.7], dtype=dtype), 1.2, 1.2),
                               torch.ones(1, dtype=dtype))  # equal indices: no interface
    with pytest.raises(SceneError, match="must be > 0"):
        fresnel_transmittance(torch.ones(2), 0.0, 1.5)


def test_prism_transmittance_of_the_apex_ray_by_hand():
    rig = thesis_setup1()
    n, a = rig.refractive_index, rig.alpha_rad
    # the camera ray along the axis meets the left face at incidence alpha, refracts to asin(sin a / n), and
    # meets the back plane at alpha - that angle (untilted prism, d = 0)
    inside = math.asin(math.sin(a) / n)
    expected = fresnel_transmittance(torch.tensor([math.cos(a)], dtype=F64), 1.0, n) * fresnel_transmittance(
        torch.tensor([math.cos(a - inside)], dtype=F64), n, 1.0)
    rays = apex_ray(rig, "left")
    rays = rays._replace(entries=rays.entries[None], origins=rays.origins[None], left=rays.left[None])
    torch.testing.assert_close(prism_transmittance(rig, rays), expected)


@pytest.mark.parametrize("make", [thesis_setup1, offset_rig, tilted_rig, thesis_setup2])
def test_prism_transmittance_from_outgoing_directions(make):
    rig = make().downscaled(16)
    rays = trace_pixels(rig, pixel_grid(rig))
    ok = rays.valid
    t = prism_transmittance(rig, rays)[ok]
    # independent: the back plane's incidence from the outgoing direction by Snell, the entry angle from the
    # camera ray and the face normal rotated by the tilt
    rot = euler_rotation(torch.tensor([math.radians(x) for x in rig.prism_tilt_deg], dtype=F64))
    sa, ca = math.sin(rig.alpha_rad), math.cos(rig.alpha_rad)
    n_face = torch.where(rays.left[ok, None], rot @ torch.tensor([sa, 0.0, ca], dtype=F64),
                         rot @ torch.tensor([-sa, 0.0, ca], dtype=F64))
    d = rays.entries[ok] / rays.entries[ok].norm(dim=-1, keepdim=True)
    cos_out = rays.directions[ok] @ rot[:, 2]
    cos_in = torch.sqrt(1.0 - (1.0 - cos_out**2) / rig.refractive_index**2)
    n = rig.refractive_index
    expected = fresnel_transmittance((d * n_face).sum(-1), 1.0, n) * fresnel_transmittance(cos_in, n, 1.0)
    torch.testing.assert_close(t, expected)


# ----------------------------------------------------------------------------------- Fresnel in the renderer
def constant_plane(depth=500.0, value=0.5):
    return Scene([Plane((0.0, 0.0, depth), (0.0, 0.0, 1.0), ConstantTexture(value))])


def test_fresnel_off_is_bit_identical():
    rig = scaled_rig(scale=16)
    scene = step_scene(rig, 420.0, 650.0, seed=4)
    default = render(rig, scene)
    off = render(rig, scene, ImageFormation(fresnel=False, f_number=None, focus_mm=900.0))
    for a, b in zip(default, off, strict=True):
        torch.testing.assert_close(a, b, rtol=0, atol=0, equal_nan=True)
    assert torch.equal(render_radiance(rig, scene, 2), render_radiance(rig, scene, 2, fresnel=False))


def test_fresnel_darkens_by_two_interfaces():
    rig = scaled_rig()
    plain = render(rig, constant_plane(), EXACT)
    lossy = render(rig, constant_plane(), ImageFormation(supersample=1, bits=None, fresnel=True))
    ratio = (lossy.image / plain.image)[0, 0]
    ok = plain.valid[0, 0]
    normal = (1.0 - (0.48 / 2.48) ** 2) ** 2  # 0.92648 for n = 1.48 at normal incidence
    h, w = rig.image_height, rig.image_width
    for u in (w // 4, 3 * w // 4):  # near the centre of each half
        assert ok[h // 2, u]
        assert abs(ratio[h // 2, u].item() - normal) < 1e-3
    assert ((ratio[ok] - normal).abs() < 2e-3).all()
    assert (lossy.image[0, 0][~ok] == 0).all()
    assert torch.equal(plain.valid, lossy.valid) and torch.equal(plain.depth.nan_to_num(), lossy.depth.nan_to_num())


def half_ratio(rig):
    """Mean Fresnel factor of the left half over that of the right half (constant plane, exact pixels)."""
    plain = render(rig, constant_plane(), EXACT)
    lossy = render(rig, constant_plane(), ImageFormation(supersample=1, bits=None, fresnel=True))
    ratio = (lossy.image.double() / plain.image.double())[0, 0]
    ok, left = plain.valid[0, 0], plain.left[0, 0]
    return (ratio[ok & left].mean() / ratio[ok & ~left].mean()).item()


def test_fresnel_halves_differ_only_on_an_asymmetric_prism():
    assert abs(half_ratio(scaled_rig()) - 1.0) < 1e-6  # symmetric rig: the halves mirror each other
    # a tilted prism changes the incidence angles of the halves differently (small near normal incidence)
    assert abs(half_ratio(scaled_rig(tilted_rig())) - 1.0) > 5e-6
    offset2 = thesis_setup2().replace(prism_offset_x_mm=3.0)
    assert abs(half_ratio(scaled_rig(offset2)) - 1.0) > 1e-4


# ----------------------------------------------------------------------------------- defocus blur
def test_disk_kernel_and_levels():
    assert disk_kernel(0.0, F64).shape == (1, 1) and disk_kernel(0.5, F64).shape == (1, 1)
    for r in (1.0, 2.3, 7.0):
        k = disk_kernel(r, F64)
        torch.testing.assert_close(k.sum(), torch.tensor(1.0, dtype=F64))
        assert torch.equal(k, k.flip(0)) and torch.equal(k, k.T)
        assert 1.0 / k[k.shape[0] // 2, k.shape[1] // 2].item() == pytest.approx(math.pi * r * r, rel=0.07)  # area
    levels = blur_levels(20.0)
    assert levels[:9] == [0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0, 3.5, 4.0] and levels[-1] >= 20.0
    assert all(b > a for a, b in zip(levels, levels[1:], strict=False))


def test_defocus_blur_constant_radius_is_a_disk_convolution(dtype):
    gen = torch.Generator().manual_seed(0)
    img = torch.rand(2, 3, 24, 31, generator=gen, dtype=dtype)
    radius = torch.full((2, 1, 24, 31), 2.5, dtype=dtype)  # exactly a level: one disk
    out = defocus_blur(img, radius)
    assert out.dtype == dtype and out.shape == img.shape
    k = disk_kernel(2.5, dtype)
    padded = torch.nn.functional.pad(img, (2, 2, 2, 2), mode="replicate")
    expected = torch.nn.functional.conv2d(padded.reshape(6, 1, 28, 35), k[None, None]).reshape(2, 3, 24, 31)
    tol = 1e-5 if dtype == torch.float32 else 1e-10
    torch.testing.assert_close(out, expected, atol=tol, rtol=0)
    # between two levels: the linear interpolation of both
    mid = defocus_blur(img, torch.full_like(radius, 2.75))
    upper = defocus_blur(img, torch.full_like(radius, 3.0))
    torch.testing.assert_close(mid, 0.5 * (out + upper), atol=tol, rtol=0)
    assert torch.equal(defocus_blur(img, torch.zeros_like(radius)), img)  # in focus: untouched
    torch.testing.assert_close(out.mean(), img.mean(), atol=0.02, rtol=0)


def test_defocus_blur_is_per_pixel():
    gen = torch.Generator().manual_seed(1)
    img = torch.rand(1, 1, 40, 60, generator=gen)
    radius = torch.zeros(1, 1, 40, 60)
    radius[..., 30:] = 4.0
    out = defocus_blur(img, radius)
    assert torch.equal(out[..., :25], img[..., :25])  # radius 0 there
    assert gradient_energy(out[..., 35:]) < 0.2 * gradient_energy(img[..., 35:])


@pytest.mark.parametrize(
    "radius,error,match",
    [(torch.full((1, 1, 4, 5), -1.0), SceneError, "finite and >= 0"),
     (torch.full((1, 1, 4, 5), math.nan), SceneError, "finite and >= 0"),
     (torch.zeros(1, 2, 4, 5), ShapeError, "radius_px must have shape")],
)
def test_defocus_blur_errors(radius, error, match):
    with pytest.raises(error, match=match):
        defocus_blur(torch.zeros(1, 1, 4, 5), radius)


def test_fill_nearest():
    depth = torch.tensor([[1.0, math.nan, math.nan, 4.0], [math.nan, math.nan, math.nan, math.nan]], dtype=F64)
    valid = torch.isfinite(depth)
    filled = fill_nearest(depth, valid, 600.0)
    assert torch.equal(filled, torch.tensor([[1.0, 1.0, 4.0, 4.0], [1.0, 1.0, 4.0, 4.0]], dtype=F64))
    assert torch.equal(fill_nearest(depth, torch.zeros_like(valid), 600.0), torch.full_like(depth, 600.0))


def test_apparent_depth_of_a_plate_like_ray():
    rig = thesis_setup1()
    rays = trace_pixels(rig, torch.tensor([[511.0, 383.5], [100.0, 50.0]], dtype=F64))
    pts = rays.origins + 300.0 * rays.directions
    z = apparent_depth(rays, pts, rig.refractive_index)
    # by hand: reduced path along the camera ray
    d = rays.entries / rays.entries.norm(dim=-1, keepdim=True)
    length = rays.entries.norm(dim=-1) + (rays.origins - rays.entries).norm(dim=-1) / 1.48 + 300.0
    torch.testing.assert_close(z, length * d[:, 2])
    # near the apex the glass is T thick: the glass shortens the path by about T (1 - 1/n)
    true_path = rays.entries.norm(dim=-1) + (rays.origins - rays.entries).norm(dim=-1) + 300.0
    assert abs((true_path[0] - length[0]).item() - rig.prism_thickness_mm * (1 - 1 / 1.48)) < 0.01


# ----------------------------------------------------------------------------------- defocus in the renderer
def test_plane_at_focus_is_unchanged():
    rig = scaled_rig()
    scene = fronto_parallel_plane(rig, 600.0, seed=2)
    pinhole = render(rig, scene, ImageFormation(supersample=2, bits=None))
    focused = render(rig, scene, ImageFormation(supersample=2, bits=None, f_number=2.0, focus_mm=600.0))
    torch.testing.assert_close(focused.image, pinhole.image, atol=1e-6, rtol=0)
    for a, b in zip(pinhole[1:], focused[1:], strict=True):  # ground truth does not depend on the lens
        torch.testing.assert_close(a, b, rtol=0, atol=0, equal_nan=True)


def test_defocus_loses_high_frequencies_more_at_small_f_number():
    rig = scaled_rig()
    scene = fronto_parallel_plane(rig, 350.0, seed=5)
    energies = []
    for n in (None, 8.0, 4.0):
        img = render(rig, scene, ImageFormation(supersample=2, bits=None, f_number=n, focus_mm=900.0)).image
        energies.append(gradient_energy(img[0, 0, 4:-4, 4:-4]))
    sharp, f8, f4 = energies  # blur circles of about 3.8 and 7.6 px
    assert f4 < f8 < 0.9 * sharp
    assert f4 < 0.7 * f8


def test_step_blurs_the_out_of_focus_side_more():
    rig = scaled_rig()
    near, far = 400.0, 700.0
    scene = step_scene(rig, near, far, seed=3)
    sharp = render(rig, scene, ImageFormation(supersample=2, bits=None))
    focus_far = render(rig, scene, ImageFormation(supersample=2, bits=None, f_number=2.0, focus_mm=far))
    focus_near = render(rig, scene, ImageFormation(supersample=2, bits=None, f_number=2.0, focus_mm=near))
    depth = sharp.depth[0, 0]
    # regions away from the step edge and the sensor border
    pool = torch.nn.functional.max_pool2d
    core = ~pool((~sharp.valid).float(), 9, 1, 4)[0, 0].bool()
    near_mask = core & ~pool((depth.nan_to_num(far) > near + 1).float()[None, None], 9, 1, 4)[0, 0].bool()
    far_mask = core & ~pool((depth.nan_to_num(near) < far - 1).float()[None, None], 9, 1, 4)[0, 0].bool()
    assert near_mask.sum() > 50 and far_mask.sum() > 50

    def kept(img, mask):
        return gradient_energy(img[0, 0], mask) / gradient_energy(sharp.image[0, 0], mask)

    # f/2 at 1/8 resolution: blur circles of about 4.7 px (near plane) and 9.6 px (far plane) where out of focus
    assert kept(focus_far.image, far_mask) > 0.95 and kept(focus_far.image, near_mask) < 0.6
    assert kept(focus_near.image, near_mask) > 0.95 and kept(focus_near.image, far_mask) < 0.6


def test_rgb_defocus_and_batch():
    rig = scaled_rig(scale=16)
    scenes = [fronto_parallel_plane(rig, 400.0, channels=3, seed=1), step_scene(rig, 450.0, 700.0, seed=2)]
    formation = ImageFormation(supersample=1, bits=None, channels=3, f_number=5.6, focus_mm=550.0, fresnel=True)
    batch = render(rig, scenes, formation)
    assert batch.image.shape == (2, 3, rig.image_height, rig.image_width) and batch.image.dtype == torch.float32
    for i, scene in enumerate(scenes):
        torch.testing.assert_close(batch.image[i:i + 1], render(rig, scene, formation).image)


# ----------------------------------------------------------------------------------- validation
@pytest.mark.parametrize(
    "kwargs,match",
    [({"f_number": 0.0}, "f_number must be a finite number > 0 or None"),
     ({"f_number": -1.4}, "f_number must be a finite number > 0 or None"),
     ({"f_number": math.inf}, "f_number must be a finite number > 0 or None"),
     ({"f_number": True}, "f_number must be a finite number > 0 or None"),
     ({"focus_mm": 0.0}, r"focus_mm must be a finite distance > 0 \(mm\)"),
     ({"focus_mm": math.nan}, r"focus_mm must be a finite distance > 0 \(mm\)"),
     ({"focus_mm": "far"}, r"focus_mm must be a finite distance > 0 \(mm\)"),
     ({"fresnel": 1}, "fresnel must be a bool")],
)
def test_formation_lens_errors(kwargs, match):
    with pytest.raises(SceneError, match=match):
        ImageFormation(**kwargs)


def test_render_rejects_focus_inside_the_focal_length():
    rig = scaled_rig(scale=16)
    with pytest.raises(SceneError, match="focus_mm must exceed the lens' focal length 25 mm, got 20"):
        render(rig, fronto_parallel_plane(rig, 500.0), ImageFormation(f_number=4.0, focus_mm=20.0))
    # without defocus the focus distance is unused
    render(rig, fronto_parallel_plane(rig, 500.0), ImageFormation(supersample=1, focus_mm=20.0))


def test_all_options_together():
    rig = scaled_rig(scale=16)
    scene = Scene([Plane((0.0, 0.0, 480.0), (0.0, 0.0, 1.0), NoiseTexture(1.0, seed=7))])
    cap = render(rig, scene, ImageFormation(supersample=1, f_number=8.0, focus_mm=700.0, fresnel=True, seed=3))
    assert torch.isfinite(cap.image).all() and (cap.image >= 0).all() and (cap.image <= 1).all()
