"""Render what the camera behind the bi-prism records, with per-pixel ground truth.

Every pixel sample is traced exactly through the prism (:func:`prismstereo.geometry.optics.trace_pixels`)
and intersected with the scene, optionally attenuated by the prism's Fresnel transmission; samples are averaged
(supersampling), then the image is formed (vignetting, thin-lens defocus, Gaussian blur, Poisson and Gaussian
noise, quantisation; the optics are in :mod:`prismstereo.synthetic.lens`). Geometry runs in float64; images
are float32 in [0, 1].

Ground truth comes from each pixel's centre ray: depth Z, the 3D point, validity (the ray passes the
prism and hits the scene), the half it belongs to, and for the reference (left) half its co-visibility
and true match in the right half: the point is projected into the right half with
:func:`~prismstereo.geometry.projection.project_points` and counts as co-visible when that pixel's own ray
reaches the same point (nothing occludes it, it is on the sensor and in the right half).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import Literal, NamedTuple

import kornia
import torch
from tqdm.auto import tqdm

from prismstereo.geometry.optics import RayBundle, pixel_directions, trace_pixels
from prismstereo.geometry.projection import project_points
from prismstereo.geometry.rig import BiPrismRig
from prismstereo.synthetic.lens import (
    apparent_depth,
    blur_circle_px,
    check_lens,
    defocus_blur,
    fill_nearest,
    fresnel_transmittance,
    positive_number,
    prism_transmittance,
)
from prismstereo.synthetic.scenes import Scene
from prismstereo.synthetic.textures import SceneError

# blur_circle_px and fresnel_transmittance live in synthetic.lens and are re-exported here.
__all__ = ["Capture", "ImageFormation", "blur_circle_px", "fresnel_transmittance", "render", "render_radiance"]

F64 = torch.float64
_CHUNK = 1 << 19
_CACHE_RAYS = 1 << 21  # rays (75 bytes each) a batch of scenes keeps, to trace them once


class Capture(NamedTuple):
    """A rendered capture of B scenes with ground truth (full sensor image, H x W).

    Attributes:
        image: (B, C, H, W) float32 in [0, 1] (quantised if the formation says so).
        depth: (B, 1, H, W) float64 depth Z (mm), NaN where invalid.
        points: (B, 3, H, W) float64 scene points (camera frame, mm), NaN where invalid.
        valid: (B, 1, H, W) bool: the pixel's centre ray passes the prism and hits a surface.
        left: (B, 1, H, W) bool: the pixel belongs to the left (reference) half-image.
        covisible: (B, 1, H, W) bool: left-half pixel whose point the right half also sees, unoccluded.
        match_uv: (B, 2, H, W) float64 right-half pixel (u, v) of co-visible left pixels, NaN elsewhere.
    """

    image: torch.Tensor
    depth: torch.Tensor
    points: torch.Tensor
    valid: torch.Tensor
    left: torch.Tensor
    covisible: torch.Tensor
    match_uv: torch.Tensor


@dataclasses.dataclass(frozen=True, kw_only=True)
class ImageFormation:
    """How radiance becomes the recorded image (all effects off except 3x3 supersampling and 8 bits).

    Thin-lens defocus (``f_number`` set): the lens (focal length ``rig.focal_length_mm``) focused at
    ``focus_mm`` blurs each pixel by a disk of diameter c = A f |Z - Z_f| / (Z (Z_f - f)), A = f / N
    (:func:`~prismstereo.synthetic.lens.blur_circle_px`), Z the apparent depth of the pixel's centre-ray point
    (reduced path through the glass, :func:`~prismstereo.synthetic.lens.apparent_depth`); pixels without a
    valid point take the nearest valid pixel's Z. Applied as a layered disk blur
    (:func:`~prismstereo.synthetic.lens.defocus_blur`) after vignetting, before ``blur_sigma_px`` and noise.
    Fresnel (``fresnel``): each sample's radiance times the prism's unpolarised transmittance at its entry face
    and back plane (:func:`~prismstereo.synthetic.lens.prism_transmittance`).

    Args:
        supersample: s x s samples per pixel (s >= 1; s = 1 samples the pixel centre only).
        channels: 1 (grey) or 3 (RGB); grey textures are repeated into RGB, RGB textures seen in grey are their
            channel mean.
        vignetting: strength in [0, 1] of cos^4 natural vignetting (0 = none).
        blur_sigma_px: global Gaussian blur (px, 0 = none), after the thin-lens defocus.
        f_number: the lens' f-number N > 0 for thin-lens defocus, or None for a pinhole (no defocus).
        focus_mm: distance the lens is focused at (mm, > 0; must exceed the rig's focal length when rendering).
        fresnel: multiply each ray's radiance by the prism's Fresnel transmittance (two interfaces).
        poisson_photons: photons at full scale for shot noise (None = none).
        noise_sigma: additive Gaussian read noise, standard deviation in [0, 1] units (1/255 = one 8-bit level).
        bits: quantise to 8 or 16 bits, or None to keep floats.
        seed: seed of the noise generator.

    Example:
        >>> ImageFormation(supersample=1, bits=None).bits is None
        True
        >>> ImageFormation(f_number=12.5, focus_mm=600.0, fresnel=True).f_number
        12.5
    """

    supersample: int = 3
    channels: int = 1
    vignetting: float = 0.0
    blur_sigma_px: float = 0.0
    poisson_photons: float | None = None
    noise_sigma: float = 0.0
    bits: Literal[8, 16] | None = 8
    seed: int = 0
    f_number: float | None = None
    focus_mm: float = 600.0
    fresnel: bool = False

    def __post_init__(self) -> None:
        if not isinstance(self.supersample, int) or self.supersample < 1:
            raise SceneError(f"supersample must be an int >= 1, got {self.supersample!r}")
        if self.channels not in (1, 3):
            raise SceneError(f"channels must be 1 or 3, got {self.channels!r}")
        if not 0.0 <= self.vignetting <= 1.0:
            raise SceneError(f"vignetting must be in [0, 1], got {self.vignetting}")
        if self.blur_sigma_px < 0 or self.noise_sigma < 0:
            raise SceneError("blur_sigma_px and noise_sigma must be >= 0")
        if self.poisson_photons is not None and not self.poisson_photons > 0:
            raise SceneError(f"poisson_photons must be positive or None, got {self.poisson_photons}")
        if self.bits not in (8, 16, None):
            raise SceneError(f"bits must be 8, 16 or None, got {self.bits!r}")
        if self.f_number is not None and not positive_number(self.f_number):
            raise SceneError(f"f_number must be a finite number > 0 or None, got {self.f_number!r}")
        if not positive_number(self.focus_mm):
            raise SceneError(f"focus_mm must be a finite distance > 0 (mm), got {self.focus_mm!r}")
        if not isinstance(self.fresnel, bool):
            raise SceneError(f"fresnel must be a bool, got {self.fresnel!r}")


def _pixel_grid(rig: BiPrismRig) -> torch.Tensor:
    v, u = torch.meshgrid(torch.arange(rig.image_height, dtype=F64), torch.arange(rig.image_width, dtype=F64),
                          indexing="ij")
    return torch.stack([u, v], dim=-1).reshape(-1, 2)


def render_radiance(
    rig: BiPrismRig, scene: Scene, supersample: int = 1, channels: int = 1, *, fresnel: bool = False
) -> torch.Tensor:
    """The noiseless image: mean radiance of ``supersample``^2 samples per pixel, (C, H, W) float32.

    Sample offsets are (k + 0.5) / s - 0.5 px in u and v, so s = 1 samples the pixel centre. Samples whose
    ray misses the prism are black; samples that hit nothing get the scene's background. With ``fresnel``
    each sample is multiplied by its ray's Fresnel transmittance through the prism
    (:func:`~prismstereo.synthetic.lens.prism_transmittance`, entry face and back plane).

    Example:
        >>> from prismstereo.synthetic import fronto_parallel_plane
        >>> small = thesis_setup1().downscaled(16)
        >>> render_radiance(small, fronto_parallel_plane(small, 525.0)).shape
        torch.Size([1, 48, 64])
    """
    scene.validate(rig)
    return _radiance(rig, scene, supersample, channels, fresnel, None)


def _traced(rig: BiPrismRig, uv: torch.Tensor, cache: dict | None, key: tuple) -> RayBundle:
    """``trace_pixels(rig, uv)``, kept in ``cache`` under ``key`` (the rays of a render's pixels do not depend on
    the scene: a batch of scenes traces them once)."""
    if cache is None:
        return trace_pixels(rig, uv)
    if key not in cache:
        cache[key] = trace_pixels(rig, uv)
    return cache[key]


def _radiance(rig: BiPrismRig, scene: Scene, s: int, channels: int, fresnel: bool, cache: dict | None) -> torch.Tensor:
    """:func:`render_radiance` with the traced rays from and into ``cache`` (None: traced here)."""
    offsets = (torch.arange(s, dtype=F64) + 0.5) / s - 0.5
    sub = torch.stack(torch.meshgrid(offsets, offsets, indexing="xy"), dim=-1).reshape(-1, 2)  # (s*s, 2)
    pixels = _pixel_grid(rig)
    total = torch.zeros(pixels.shape[0], channels, dtype=torch.float32)
    per_chunk = max(1, _CHUNK // (s * s))
    for start in range(0, pixels.shape[0], per_chunk):
        uv = (pixels[start:start + per_chunk, None, :] + sub[None]).reshape(-1, 2)
        rays = _traced(rig, uv, cache, ("samples", s, start))
        hit, index = scene.intersect(rays.origins, rays.directions)
        values = scene.shade(hit, index, channels)
        if fresnel:
            values = values * prism_transmittance(rig, rays).to(values.dtype).unsqueeze(-1)
        values[~rays.valid] = 0.0
        total[start:start + per_chunk] = values.view(-1, s * s, channels).mean(dim=1)
    return total.T.reshape(channels, rig.image_height, rig.image_width)


def _ground_truth(rig: BiPrismRig, scene: Scene, lens: bool = False,
                  cache: dict | None = None) -> tuple[torch.Tensor, ...]:
    """Centre-ray ground truth: points (N, 3), valid, left, covisible (N,), match (N, 2) and, with ``lens``, the
    apparent depth (N,) the lens sees (NaN where invalid; all NaN without ``lens``); the centre rays from and into
    ``cache``."""
    pixels = _pixel_grid(rig)
    n = pixels.shape[0]
    points = torch.full((n, 3), float("nan"), dtype=F64)
    apparent = torch.full((n,), float("nan"), dtype=F64)
    valid = torch.zeros(n, dtype=torch.bool)
    left = torch.zeros(n, dtype=torch.bool)
    covisible = torch.zeros(n, dtype=torch.bool)
    match = torch.full((n, 2), float("nan"), dtype=F64)
    for start in range(0, n, _CHUNK):
        sl = slice(start, start + _CHUNK)
        rays = _traced(rig, pixels[sl], cache, ("centres", start))
        hit, _ = scene.intersect(rays.origins, rays.directions)
        ok = rays.valid & torch.isfinite(hit.t)
        points[sl][ok] = hit.points[ok]
        if lens:
            apparent[sl][ok] = apparent_depth(rays, hit.points, rig.refractive_index)[ok]
        valid[sl], left[sl] = ok, rays.left
        ref = ok & rays.left
        if ref.any():
            x = hit.points[ref]
            proj = project_points(rig, x, "right")
            back = trace_pixels(rig, proj.uv)
            again, _ = scene.intersect(back.origins, back.directions)
            tol = 1e-3 + 1e-6 * x[:, 2]
            seen = proj.valid & back.valid & ~back.left & ((again.points - x).norm(dim=-1) < tol)
            idx = torch.nonzero(ref).squeeze(1) + start
            covisible[idx] = seen
            match[idx[seen]] = proj.uv[seen]
    return points, valid, left, covisible, match, apparent


def _form_image(
    radiance: torch.Tensor, rig: BiPrismRig, formation: ImageFormation, gen: torch.Generator,
    lens_depth: torch.Tensor | None = None,
) -> torch.Tensor:
    """(C, H, W) radiance -> recorded image; ``lens_depth`` (H, W) is the apparent depth used for defocus."""
    img = radiance
    if formation.vignetting > 0:
        d = pixel_directions(rig, _pixel_grid(rig))
        cos4 = d[:, 2].pow(4).to(torch.float32).view(1, rig.image_height, rig.image_width)
        img = img * (1.0 - formation.vignetting + formation.vignetting * cos4)
    if formation.f_number is not None and lens_depth is not None:
        radius = 0.5 * blur_circle_px(rig, lens_depth, formation.f_number, formation.focus_mm)
        img = defocus_blur(img[None], radius.to(img.dtype)[None, None])[0]
    if formation.blur_sigma_px > 0:
        sigma = formation.blur_sigma_px
        k = 2 * int(3 * sigma + 0.5) + 1
        img = kornia.filters.gaussian_blur2d(img[None], (k, k), (sigma, sigma), border_type="replicate")[0]
    if formation.poisson_photons is not None:
        img = torch.poisson(img.clamp_min(0) * formation.poisson_photons, generator=gen) / formation.poisson_photons
    if formation.noise_sigma > 0:
        img = img + formation.noise_sigma * torch.randn(img.shape, generator=gen)
    img = img.clamp(0.0, 1.0)
    if formation.bits is not None:
        levels = float(2**formation.bits - 1)
        img = torch.round(img * levels) / levels
    return img


def render(
    rig: BiPrismRig,
    scenes: Scene | Sequence[Scene],
    formation: ImageFormation | None = None,
    *,
    progress: bool = False,
) -> Capture:
    """Render one or more scenes through the rig, with ground truth (see :class:`Capture`).

    Args:
        rig: the rig.
        scenes: a :class:`~prismstereo.synthetic.scenes.Scene` or a sequence of them (the batch).
        formation: image formation options, default :class:`ImageFormation` () (3x3 supersampling, 8 bits).
        progress: show a progress bar over the batch (where stderr is a terminal).

    Returns:
        Capture with batch B = number of scenes.

    Raises:
        SceneError: a surface at or before the prism's back plane, or invalid options (also a ``focus_mm`` not
            beyond the rig's focal length when ``formation.f_number`` is set).

    Example:
        >>> from prismstereo.synthetic import fronto_parallel_plane
        >>> small = thesis_setup1().downscaled(16)
        >>> cap = render(small, fronto_parallel_plane(small, 525.0), ImageFormation(supersample=1))
        >>> cap.image.shape, cap.depth.shape
        (torch.Size([1, 1, 48, 64]), torch.Size([1, 1, 48, 64]))
    """
    scenes = [scenes] if isinstance(scenes, Scene) else list(scenes)
    if not scenes or not all(isinstance(s, Scene) for s in scenes):
        raise SceneError("scenes must be a Scene or a non-empty sequence of Scenes")
    formation = formation or ImageFormation()
    if formation.f_number is not None:
        check_lens(rig, formation.f_number, formation.focus_mm)
    for scene in scenes:
        scene.validate(rig)
    gen = torch.Generator().manual_seed(formation.seed)
    h, w = rig.image_height, rig.image_width
    out: list[list[torch.Tensor]] = [[] for _ in Capture._fields]
    # a batch traces its rays once, where they fit in _CACHE_RAYS
    cache = {} if len(scenes) > 1 and h * w * (formation.supersample ** 2 + 1) <= _CACHE_RAYS else None
    for scene in tqdm(scenes, desc="render", disable=None if progress else True):
        radiance = _radiance(rig, scene, formation.supersample, formation.channels, formation.fresnel, cache)
        points, valid, left, covisible, match, apparent = _ground_truth(rig, scene, formation.f_number is not None,
                                                                        cache)
        lens_depth = None
        if formation.f_number is not None:
            lens_depth = fill_nearest(apparent.view(h, w), valid.view(h, w), formation.focus_mm)
        image = _form_image(radiance, rig, formation, gen, lens_depth)
        fields = (
            image,
            points[:, 2].view(1, h, w),
            points.T.reshape(3, h, w),
            valid.view(1, h, w),
            left.view(1, h, w),
            covisible.view(1, h, w),
            match.T.reshape(2, h, w),
        )
        for acc, value in zip(out, fields, strict=True):
            acc.append(value)
    return Capture(*(torch.stack(acc) for acc in out))
