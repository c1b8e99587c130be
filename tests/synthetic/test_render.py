
import pytest
import torch

from prismstereo import thesis_setup1, thesis_setup2
from prismstereo.geometry import points_at_depth, project_points, trace_pixels
from prismstereo.synthetic import (
    Capture,
    ConstantTexture,
    ImageFormation,
    NoiseTexture,
    Plane,
    Scene,
    SceneError,
    fronto_parallel_plane,
    render,
    render_radiance,
    sphere_scene,
    step_scene,
)
from tests.conftest import scaled_rig

F64 = torch.float64


def pixel_grid(rig):
    v, u = torch.meshgrid(torch.arange(rig.image_height, dtype=F64), torch.arange(rig.image_width, dtype=F64),
                          indexing="ij")
    return torch.stack([u, v], dim=-1)


EXACT = ImageFormation(supersample=1, bits=None)


def test_capture_shapes_and_types():
    rig = scaled_rig()
    cap = render(rig, fronto_parallel_plane(rig, 525.0), ImageFormation(supersample=2, channels=3))
    assert isinstance(cap, Capture)
    h, w = rig.image_height, rig.image_width
    assert cap.image.shape == (1, 3, h, w) and cap.image.dtype == torch.float32
    assert cap.depth.shape == (1, 1, h, w) and cap.points.shape == (1, 3, h, w) and cap.match_uv.shape == (1, 2, h, w)
    for mask in (cap.valid, cap.left, cap.covisible):
        assert mask.shape == (1, 1, h, w) and mask.dtype == torch.bool
    assert torch.equal(cap.image[:, 0], cap.image[:, 1])  # grey texture repeated into RGB
    colour = fronto_parallel_plane(rig, 525.0, channels=3)  # an RGB texture on a grey sensor: its channel mean
    rgb = render(rig, colour, ImageFormation(supersample=2, channels=3, bits=None))
    grey = render(rig, colour, ImageFormation(supersample=2, channels=1, bits=None))
    assert not torch.equal(rgb.image[:, 0], rgb.image[:, 1])
    torch.testing.assert_close(grey.image, rgb.image.mean(1, keepdim=True))


@pytest.mark.parametrize("make", [thesis_setup1, thesis_setup2])
def test_fronto_parallel_depth_is_exact(make):
    rig = scaled_rig(make())
    cap = render(rig, fronto_parallel_plane(rig, 612.5), EXACT)
    assert cap.valid.float().mean() > 0.8
    depth = cap.depth[cap.valid]
    assert torch.equal(depth, torch.full_like(depth, 612.5))
    assert torch.isnan(cap.depth[~cap.valid]).all()
    torch.testing.assert_close(cap.points[:, 2:3][cap.valid], depth)


def test_ground_truth_points_lie_on_pixel_rays():
    rig = scaled_rig()
    cap = render(rig, sphere_scene(rig, 450.0, 40.0, 650.0), EXACT)
    rays = trace_pixels(rig, pixel_grid(rig))
    pts = cap.points[0].permute(1, 2, 0)
    ok = cap.valid[0, 0]
    rel = pts[ok] - rays.origins[ok]
    assert torch.linalg.cross(rel, rays.directions[ok]).norm(dim=-1).max() < 1e-8
    assert torch.equal(cap.left[0, 0], rays.left)


def test_intensity_equals_texture_at_hit_point():
    rig = scaled_rig()
    tex = NoiseTexture(1.0, seed=3)
    scene = Scene([Plane((0.0, 0.0, 500.0), (0.0, 0.0, 1.0), tex)])
    cap = render(rig, scene, EXACT)
    # independent: trace pixel centres, intersect Z = 500 by hand, sample the texture there
    rays = trace_pixels(rig, pixel_grid(rig))
    pts = points_at_depth(rays, 500.0)
    expected = tex.sample(pts[..., :2].reshape(-1, 2)).view(rig.image_height, rig.image_width).to(torch.float32)
    ok = rays.valid
    torch.testing.assert_close(cap.image[0, 0][ok], expected[ok], atol=1e-6, rtol=0)
    assert (cap.image[0, 0][~ok] == 0).all()


class MirrorTexture:
    """Any texture made mirror-symmetric about s = 0."""

    def __init__(self, base):
        self.base, self.channels = base, base.channels

    def sample(self, coords):
        return self.base.sample(torch.stack([coords[:, 0].abs(), coords[:, 1]], dim=-1))


def test_halves_mirror_each_other_on_a_symmetric_rig():
    rig = scaled_rig()  # d = 0, principal point at the image centre
    scene = Scene([Plane((0.0, 0.0, 550.0), (0.0, 0.0, 1.0), MirrorTexture(NoiseTexture(0.8, seed=9)))])
    cap = render(rig, scene, ImageFormation(supersample=2, bits=None))
    torch.testing.assert_close(cap.image, cap.image.flip(-1), atol=1e-6, rtol=0)
    assert torch.equal(cap.valid, cap.valid.flip(-1)) and torch.equal(cap.left, ~cap.left.flip(-1))
    torch.testing.assert_close(cap.depth, cap.depth.flip(-1), equal_nan=True)


def test_covisibility_of_a_step_matches_independent_check():
    rig = scaled_rig(scale=4)
    near, far = 400.0, 600.0
    cap = render(rig, step_scene(rig, near, far), EXACT)
    pts = cap.points[0].permute(1, 2, 0)
    ref = cap.valid[0, 0] & cap.left[0, 0]
    x = pts[ref]
    # independent check: project into the right half, trace back, and intersect the two planes by hand
    proj = project_points(rig, x, "right")
    back = trace_pixels(rig, proj.uv)
    o, d = back.origins, back.directions
    at_near = o + ((near - o[:, 2]) / d[:, 2])[:, None] * d
    at_far = o + ((far - o[:, 2]) / d[:, 2])[:, None] * d
    first = torch.where((at_near[:, 0] >= 0)[:, None], at_near, at_far)  # near plane: x >= 0
    expected = proj.valid & back.valid & ~back.left & ((first - x).norm(dim=-1) < 1e-6)
    got = cap.covisible[0, 0][ref]
    assert torch.equal(got, expected)
    # the step really occludes: some points the right half could see in its field of view are hidden
    hidden = proj.valid & ((first - x).norm(dim=-1) > 1.0)
    assert hidden.any()
    assert not cap.covisible[0, 0][~cap.left[0, 0]].any()


def test_match_uv_is_the_true_correspondence():
    rig = scaled_rig(scale=4)
    cap = render(rig, sphere_scene(rig, 450.0, 40.0, 650.0), EXACT)
    cov = cap.covisible[0, 0]
    uv = cap.match_uv[0].permute(1, 2, 0)[cov]
    rays = trace_pixels(rig, uv)
    pts = cap.points[0].permute(1, 2, 0)[cov]
    assert (~rays.left).all()
    rel = pts - rays.origins
    assert torch.linalg.cross(rel, rays.directions).norm(dim=-1).max() < 1e-6
    assert torch.isnan(cap.match_uv[0].permute(1, 2, 0)[~cov]).all()


def test_supersampling_antialiases():
    rig = scaled_rig()
    scene = Scene([Plane((0.0, 0.0, 500.0), (0.0, 0.0, 1.0), NoiseTexture(0.2, seed=1))])
    one = render_radiance(rig, scene, 1)
    four = render_radiance(rig, scene, 4)
    assert four.std() < one.std()  # averaging sub-pixel samples removes aliased high frequencies
    assert abs(four.mean() - one.mean()) < 0.02


def test_image_formation_effects():
    rig = scaled_rig()
    scene = Scene([Plane((0.0, 0.0, 500.0), (0.0, 0.0, 1.0), ConstantTexture(0.5))])
    flat = render(rig, scene, ImageFormation(supersample=1, bits=None)).image
    vig = render(rig, scene, ImageFormation(supersample=1, bits=None, vignetting=1.0)).image
    h, w = rig.image_height, rig.image_width
    assert vig[0, 0, h // 2, w // 2 - 1] > vig[0, 0, 0, 0] and vig[0, 0, 0, 0] < flat[0, 0, 0, 0]
    noisy = render(rig, scene, ImageFormation(supersample=1, bits=None, noise_sigma=0.02, seed=1)).image
    assert abs((noisy - flat)[flat > 0].std().item() - 0.02) < 0.003
    again = render(rig, scene, ImageFormation(supersample=1, bits=None, noise_sigma=0.02, seed=1)).image
    assert torch.equal(noisy, again)
    shot = render(rig, scene, ImageFormation(supersample=1, bits=None, poisson_photons=1000.0, seed=2)).image
    assert abs((shot - flat)[flat > 0].var().item() - 0.5 / 1000.0) < 1e-4
    q8 = render(rig, scene, ImageFormation(supersample=1, bits=8, noise_sigma=0.01)).image
    torch.testing.assert_close(q8 * 255, torch.round(q8 * 255))
    q16 = render(rig, scene, ImageFormation(supersample=1, bits=16, noise_sigma=0.01)).image
    torch.testing.assert_close(q16 * 65535, torch.round(q16 * 65535))
    textured = Scene([Plane((0.0, 0.0, 500.0), (0.0, 0.0, 1.0), NoiseTexture(0.3, seed=2))])
    sharp = render(rig, textured, ImageFormation(supersample=1, bits=None)).image
    blurred = render(rig, textured, ImageFormation(supersample=1, bits=None, blur_sigma_px=1.5)).image
    assert blurred.std() < sharp.std()


def test_batch_equals_single_renders():
    rig = scaled_rig()
    scenes = [fronto_parallel_plane(rig, 400.0, seed=1), step_scene(rig, 450.0, 700.0, seed=2)]
    batch = render(rig, scenes, EXACT)  # (a batch traces its rays once and reuses them: bit for bit the same)
    assert batch.image.shape[0] == 2
    for i, scene in enumerate(scenes):
        single = render(rig, scene, EXACT)
        for a, b in zip(batch, single, strict=True):
            torch.testing.assert_close(a[i:i + 1], b, equal_nan=True, rtol=0.0, atol=0.0)


@pytest.mark.parametrize(
    "kwargs,match",
    [({"supersample": 0}, "supersample must be an int >= 1"), ({"channels": 2}, "channels must be 1 or 3"),
     ({"vignetting": 2.0}, r"vignetting must be in \[0, 1\]"), ({"noise_sigma": -1.0}, "must be >= 0"),
     ({"poisson_photons": 0.0}, "poisson_photons must be positive"), ({"bits": 12}, "bits must be 8, 16 or None")],
)
def test_formation_errors(kwargs, match):
    with pytest.raises(SceneError, match=match):
        ImageFormation(**kwargs)


def test_render_errors():
    rig = scaled_rig()
    with pytest.raises(SceneError, match="not beyond the prism's back plane"):
        render(rig, fronto_parallel_plane(rig, 170.0))
    with pytest.raises(SceneError, match="non-empty sequence of Scenes"):
        render(rig, [])
