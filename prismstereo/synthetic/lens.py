"""Optics of image formation behind the bi-prism: thin-lens defocus and Fresnel transmission of the prism.

Defocus (thin lens of focal length f, f-number N, aperture A = f / N, focused at distance Z_f): a point at
distance Z is imaged as a blur circle of diameter

    c = A f |Z - Z_f| / (Z (Z_f - f))   (mm on the sensor; / pixel size for px).

Behind the prism the lens sees a virtual image of the scene point, not the point itself. Its distance is
approximated by the *reduced* (air-equivalent) path along the pixel's ray, L = |P1| + |P2 - P1| / n + |X - P2|
(camera centre -> entry P1 -> exit P2 -> scene point X), placed on the camera ray: Z_v = L d_z. For a plate at
normal incidence this is the exact paraxial image (shifted T (1 - 1/n) towards the camera); the wedge's
small astigmatism at oblique incidence is neglected. :func:`defocus_blur` applies a per-pixel blur circle as
a layered disk blur (gather form: each pixel averages its neighbourhood over its own circle).

Fresnel: unpolarised power transmittance T = 1 - (R_s + R_p) / 2 of each interface a ray crosses, air -> glass
at the inclined entry face and glass -> air at the back plane (:func:`prism_transmittance`).
"""

from __future__ import annotations

import math

import cv2
import numpy as np
import torch

from prismstereo.errors import check_floating, check_shape
from prismstereo.geometry.optics import RayBundle
from prismstereo.geometry.parameters import RigParameters
from prismstereo.geometry.rig import BiPrismRig, as_parameters
from prismstereo.geometry.surfaces import euler_rotation
from prismstereo.synthetic.textures import SceneError

__all__ = [
    "apparent_depth", "blur_circle_px", "blur_levels", "check_lens", "defocus_blur", "disk_kernel", "fill_nearest",
    "fresnel_transmittance", "positive_number", "prism_transmittance",
]

_FINE_STEP_PX = 0.5  # radius spacing of the blur levels up to 4 px; above, levels grow geometrically by 1/8
_LEVEL_RATIO = 1.0 / 8.0


def positive_number(value: object) -> bool:
    """A finite int or float > 0 (not a bool): an f-number or a distance.

    Example:
        >>> positive_number(2.8), positive_number(True), positive_number(float("inf"))
        (True, False, False)
    """
    return (not isinstance(value, bool) and isinstance(value, (int, float)) and math.isfinite(value)
            and value > 0)


def check_lens(rig: BiPrismRig, f_number: float, focus_mm: float) -> None:
    """Raise :class:`SceneError` unless f_number > 0 and the focus distance lies beyond the focal length.

    Example:
        >>> check_lens(thesis_setup1(), 2.8, 600.0)
        >>> check_lens(thesis_setup1(), 2.8, 10.0)
        Traceback (most recent call last):
        ...
        prismstereo.synthetic.textures.SceneError: focus_mm must exceed the lens' focal length ...
    """
    if not positive_number(f_number):
        raise SceneError(f"f_number must be a finite number > 0, got {f_number!r}")
    if isinstance(focus_mm, bool) or not isinstance(focus_mm, (int, float)) or not math.isfinite(focus_mm):
        raise SceneError(f"focus_mm must be a finite number, got {focus_mm!r}")
    if focus_mm <= rig.focal_length_mm:
        raise SceneError(f"focus_mm must exceed the lens' focal length {rig.focal_length_mm:g} mm, got {focus_mm:g}")


def blur_circle_px(rig: BiPrismRig, depth_mm: torch.Tensor, f_number: float, focus_mm: float) -> torch.Tensor:
    """Thin-lens blur-circle diameter on the sensor (px) of points at distance ``depth_mm``.

    c = A f |Z - Z_f| / (Z (Z_f - f)) / pixel_size with A = f / N, f = ``rig.focal_length_mm`` and the pixel
    size ``rig.pixel_size_mm``. Z = inf gives the limit A f / (Z_f - f); NaN stays NaN.

    Args:
        rig: the rig (its focal length and pixel size).
        depth_mm: (*) object distance Z along the optical axis as the lens sees it (mm; the renderer passes
            the apparent depth :func:`apparent_depth`), positive, NaN or inf.
        f_number: N > 0.
        focus_mm: focus distance Z_f (mm), beyond the focal length.

    Returns:
        (*) blur-circle diameters in px, dtype of ``depth_mm``.

    Raises:
        SceneError: f_number <= 0, focus_mm <= f, or a depth <= 0.
        ShapeError: ``depth_mm`` is not a tensor.

    Example:
        >>> blur_circle_px(thesis_setup1(), torch.tensor([400.0, 600.0]), f_number=12.5, focus_mm=600.0)
        tensor([9.3502, 0.0000])
    """
    check_shape(depth_mm, ["*"], "depth_mm")
    check_floating(depth_mm, "depth_mm")
    check_lens(rig, f_number, focus_mm)
    if (depth_mm <= 0).any():
        raise SceneError("depth_mm must be positive (NaN and inf are allowed)")
    f = rig.focal_length_mm
    aperture = f / f_number
    return (aperture * f / ((focus_mm - f) * rig.pixel_size_mm)) * (1.0 - focus_mm / depth_mm).abs()


def apparent_depth(rays: RayBundle, points: torch.Tensor, refractive_index: torch.Tensor | float) -> torch.Tensor:
    """Distance along the optical axis of the virtual image the lens sees of each ray's scene point.

    Z_v = d_z (|P1| + |P2 - P1| / n + |X - P2|): the reduced (air-equivalent) path from the camera centre
    through entry P1 and exit P2 to the point X, laid along the camera ray d = P1 / |P1| (the rays start at the
    camera centre). Exact paraxially for a plate at normal incidence; neglects the wedge's astigmatism.

    Args:
        rays: RayBundle of the camera rays (entries, origins (*, 3)), e.g. from
            :func:`~prismstereo.geometry.optics.trace_pixels`.
        points: (*, 3) scene points on the rays' outgoing parts (mm).
        refractive_index: n of the glass (float or tensor broadcastable to (*,)).

    Returns:
        (*) apparent depths (mm), dtype of ``points``; NaN where ``points`` is NaN.

    Example:
        >>> from prismstereo.geometry.optics import points_at_depth, trace_pixels
        >>> rays = trace_pixels(thesis_setup1(), torch.tensor([[300.0, 383.5]], dtype=torch.float64))
        >>> round(apparent_depth(rays, points_at_depth(rays, 600.0), 1.48).item(), 2)  # glass counts 1/n: closer
        598.14
    """
    check_shape(points, ["*", 3], "points")
    check_floating(points, "points")
    entry = rays.entries.norm(dim=-1)
    glass = (rays.origins - rays.entries).norm(dim=-1)
    air = (points - rays.origins).norm(dim=-1)
    return (entry + glass / refractive_index + air) * rays.entries[..., 2] / entry


def fresnel_transmittance(
    cos_incidence: torch.Tensor, n_from: torch.Tensor | float, n_to: torch.Tensor | float
) -> torch.Tensor:
    """Unpolarised Fresnel power transmittance T = 1 - (R_s + R_p) / 2 of an interface n_from -> n_to.

    With cos_t = sqrt(1 - (n_from / n_to)^2 (1 - cos_i^2)):
    r_s = (n1 cos_i - n2 cos_t) / (n1 cos_i + n2 cos_t), r_p = (n2 cos_i - n1 cos_t) / (n2 cos_i + n1 cos_t),
    R = r^2. Beyond the critical angle (total internal reflection) T = 0; at grazing incidence T = 0; never NaN.

    Args:
        cos_incidence: (*) cosine of the angle between the ray and the surface normal; its absolute value is
            used (either normal orientation), clamped to [0, 1].
        n_from: refractive index of the incident side (> 0, float or tensor broadcastable to (*)).
        n_to: refractive index of the transmitted side (> 0, float or tensor broadcastable to (*)).

    Returns:
        (*) transmittance in [0, 1], dtype of ``cos_incidence``.

    Raises:
        SceneError: a non-positive refractive index.

    Example:
        >>> fresnel_transmittance(torch.tensor([1.0, 0.0]), 1.0, 1.5)   # normal: 1 - (0.5 / 2.5)^2
        tensor([0.9600, 0.0000])
    """
    check_shape(cos_incidence, ["*"], "cos_incidence")
    check_floating(cos_incidence, "cos_incidence")
    n1 = torch.as_tensor(n_from, dtype=cos_incidence.dtype, device=cos_incidence.device)
    n2 = torch.as_tensor(n_to, dtype=cos_incidence.dtype, device=cos_incidence.device)
    if not ((n1 > 0).all() and (n2 > 0).all()):
        raise SceneError("refractive indices n_from and n_to must be > 0")
    cos_i = cos_incidence.abs().clamp(max=1.0)
    sin2_t = (n1 / n2) ** 2 * (1.0 - cos_i * cos_i)
    transmitted = sin2_t < 1.0
    cos_t = torch.sqrt((1.0 - sin2_t).clamp_min(0.0))
    den_s, den_p = n1 * cos_i + n2 * cos_t, n2 * cos_i + n1 * cos_t
    ok = transmitted & (den_s > 0) & (den_p > 0)  # den = 0 only at grazing incidence on equal indices
    one = torch.ones_like(den_s)
    r_s = (n1 * cos_i - n2 * cos_t) / torch.where(ok, den_s, one)
    r_p = (n2 * cos_i - n1 * cos_t) / torch.where(ok, den_p, one)
    t = 1.0 - 0.5 * (r_s * r_s + r_p * r_p)
    return torch.where(ok, t.clamp(0.0, 1.0), torch.zeros_like(t))


def prism_transmittance(rig: BiPrismRig | RigParameters, rays: RayBundle) -> torch.Tensor:
    """Fresnel transmittance of the prism along traced rays: entry face (air -> glass) times back plane.

    The incidence angles are those of the camera ray d = P1 / |P1| on the face it enters (the left face for
    ``rays.left``) and of the internal ray (P2 - P1) / |P2 - P1| on the back plane; each interface transmits
    :func:`fresnel_transmittance` of its angle. Multiple reflections inside the glass are neglected.

    Args:
        rig: the rig (its prism angle, tilt and refractive index).
        rays: RayBundle (entries, origins (*, 3), left (*,)) from
            :func:`~prismstereo.geometry.optics.trace_pixels`.

    Returns:
        (*) transmittance in [0, 1], dtype of the rays (meaningless where ``rays.valid`` is False).

    Example:
        >>> from prismstereo.geometry.optics import trace_pixels
        >>> rays = trace_pixels(thesis_setup1(), torch.tensor([[511.0, 383.5]]))
        >>> round(prism_transmittance(thesis_setup1(), rays).item(), 4)   # ~ (1 - (0.48 / 2.48)^2)^2
        0.9265
    """
    p = as_parameters(rig, rays.entries)
    sa, ca, zero = torch.sin(p.alpha), torch.cos(p.alpha), torch.zeros_like(p.alpha)
    rot = euler_rotation(p.tilt)
    n_left, n_right = rot @ torch.stack([sa, zero, ca]), rot @ torch.stack([-sa, zero, ca])
    n_face = torch.where(rays.left.unsqueeze(-1), n_left, n_right)
    camera = rays.entries / rays.entries.norm(dim=-1, keepdim=True)
    inside = rays.origins - rays.entries
    inside = inside / inside.norm(dim=-1, keepdim=True).clamp_min(torch.finfo(inside.dtype).tiny)
    cos_entry = (camera * n_face).sum(-1)
    cos_back = inside @ rot[:, 2]
    return fresnel_transmittance(cos_entry, 1.0, p.n) * fresnel_transmittance(cos_back, p.n, 1.0)


def blur_levels(max_radius: float) -> list[float]:
    """The blur radii :func:`defocus_blur` renders exactly and blends between: 0, 0.5, ..., 4 px, then each 1/8
    larger than the last, up to >= ``max_radius``.

    Example:
        >>> blur_levels(5.0)[:3], blur_levels(5.0)[-1] >= 5.0
        ([0.0, 0.5, 1.0], True)
    """
    levels = [0.0]
    while levels[-1] < max_radius:
        levels.append(levels[-1] + max(_FINE_STEP_PX, _LEVEL_RATIO * levels[-1]))
    if len(levels) == 1:
        levels.append(_FINE_STEP_PX)
    return levels


def _kernel_half_size(radius: float) -> int:
    """The largest integer offset with a non-zero pillbox weight, i < radius + 1/2."""
    return max(0, math.ceil(radius + 0.5) - 1)


def disk_kernel(radius: float, dtype: torch.dtype) -> torch.Tensor:
    """(2R + 1, 2R + 1) pillbox of the given radius (px), summing to 1, the thin lens' circle of confusion; its edge
    is anti-aliased: weight clamp(radius + 1/2 - distance, 0, 1), so R = ceil(radius + 1/2) - 1. Radius <= 1/2 is
    the identity (1, 1).

    Example:
        >>> disk_kernel(2.0, torch.float64).shape, float(disk_kernel(2.0, torch.float64).sum())
        (torch.Size([5, 5]), 1.0)
    """
    size = _kernel_half_size(radius)
    offsets = torch.arange(-size, size + 1, dtype=dtype)
    dist = torch.sqrt(offsets[:, None] ** 2 + offsets[None, :] ** 2)
    kernel = (radius + 0.5 - dist).clamp(0.0, 1.0)
    return kernel / kernel.sum()


def defocus_blur(image: torch.Tensor, radius_px: torch.Tensor) -> torch.Tensor:
    """Blur every pixel with a disk of its own radius (a layered approximation of depth-dependent defocus).

    The radii are quantised to levels r_k (0, 0.5, 1, ..., 4 px, then 12.5 % apart); the image is convolved
    with an anti-aliased pillbox of each level that some pixel needs (FFT, replicate border) and each pixel
    takes the linear interpolation of the two levels bracketing its radius. Levels of radius <= 1/2 px are the
    identity, so in-focus pixels are returned unchanged. This is the gather form of defocus: at depth edges
    a blurred background pixel averages in its sharp neighbours (no occlusion-aware scattering).

    Args:
        image: (B, C, H, W) floating images.
        radius_px: (B, 1, H, W) blur-circle radius per pixel (px), finite and >= 0.

    Returns:
        (B, C, H, W) blurred images, dtype of ``image``.

    Raises:
        SceneError: a negative or non-finite radius.

    Example:
        >>> img = torch.zeros(1, 1, 9, 9); img[..., 4, 4] = 1.0
        >>> out = defocus_blur(img, torch.full((1, 1, 9, 9), 2.0))
        >>> out.shape, round(out.sum().item(), 4)
        (torch.Size([1, 1, 9, 9]), 1.0)
    """
    check_shape(image, ["B", "C", "H", "W"], "image")
    check_floating(image, "image")
    check_shape(radius_px, [image.shape[0], 1, image.shape[2], image.shape[3]], "radius_px")
    radius = radius_px.to(image.dtype)
    if not (torch.isfinite(radius).all() and (radius >= 0).all()):
        raise SceneError("radius_px must be finite and >= 0")
    r_max = float(radius.max()) if radius.numel() else 0.0
    if r_max <= 0.5:
        return image
    levels = torch.tensor(blur_levels(r_max), dtype=image.dtype, device=image.device)
    index = (torch.searchsorted(levels, radius.contiguous(), right=True) - 1).clamp(0, levels.numel() - 2)
    frac = ((radius - levels[index]) / (levels[index + 1] - levels[index])).clamp(0.0, 1.0)
    pad = _kernel_half_size(float(levels[int(index.max()) + 1]))
    padded = torch.nn.functional.pad(image, (pad, pad, pad, pad), mode="replicate")
    hp, wp = padded.shape[-2:]
    spectrum = torch.fft.rfft2(padded)
    out = torch.zeros_like(image)
    for k in range(levels.numel()):
        weight = torch.where(index == k, 1.0 - frac, torch.zeros_like(frac)) + torch.where(
            index + 1 == k, frac, torch.zeros_like(frac))
        if not (weight > 0).any():
            continue
        kernel = disk_kernel(float(levels[k]), image.dtype).to(image.device)
        if kernel.shape[-1] == 1:
            out = out + weight * image
            continue
        r = kernel.shape[-1] // 2
        full = torch.zeros(hp, wp, dtype=image.dtype, device=image.device)
        full[: 2 * r + 1, : 2 * r + 1] = kernel
        full = torch.roll(full, shifts=(-r, -r), dims=(0, 1))  # kernel centre at (0, 0): no shift
        blurred = torch.fft.irfft2(spectrum * torch.fft.rfft2(full), s=(hp, wp))
        out = out + weight * blurred[..., pad:pad + image.shape[-2], pad:pad + image.shape[-1]]
    return out


def fill_nearest(depth: torch.Tensor, valid: torch.Tensor, default: float) -> torch.Tensor:
    """(H, W) depth with every invalid pixel set to the depth of its nearest valid pixel (OpenCV's 5x5-mask
    distance transform); all ``default`` when no pixel is valid.

    Example:
        >>> fill_nearest(torch.tensor([[1.0, 0.0, 0.0, 4.0]]), torch.tensor([[True, False, False, True]]), 9.0)
        tensor([[1., 1., 4., 4.]])
    """
    if bool(valid.all()):
        return depth
    if not bool(valid.any()):
        return torch.full_like(depth, default)
    mask = (~valid).cpu().numpy().astype(np.uint8)  # zeros (valid pixels) are the sources
    _, labels = cv2.distanceTransformWithLabels(mask, cv2.DIST_L2, cv2.DIST_MASK_5, labelType=cv2.DIST_LABEL_PIXEL)
    labels = torch.from_numpy(labels.astype(np.int64)).to(depth.device)
    lut = torch.zeros(int(labels.max()) + 1, dtype=depth.dtype, device=depth.device)
    lut[labels[valid]] = depth[valid]
    return lut[labels]
