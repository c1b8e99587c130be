"""Training captures for :class:`~prismstereo.learned.hybrid.HybridStereo`: varied rigs, ranges, photographs and
image formation, each stored with the classical estimate the refinement starts from.

Scenes alternate between this package's procedural kinds (:func:`~prismstereo.learned.data.random_capture_spec`:
noise-textured planes, slanted planes, steps, spheres, weakly textured height fields) and photographs as surfaces:
one of scikit-image's bundled photographs (:data:`TRAIN_PHOTOS`; its stereo Motorcycle and the Middlebury pairs are
kept for evaluation) cropped and draped over a height field of smooth relief, a slant, and depth jumps along the
photograph's own edges (regions of a thresholded, blurred copy of it moved nearer), as objects in real photographs
are. Image formation varies read noise, blur, thin-lens defocus, Fresnel and vignetting in the render, then gamma
(0.7-1.4) and a brightness ratio of the halves (0.85-1.15) on the 8-bit capture. Rigs (:func:`training_rigs`): the
thesis' two setups at their default and narrower ranges, and setup 1 with another prism angle, apex distance and a
barrel distortion.

Rendering dominates; :func:`render_set` keeps each rig's binned captures and truth in a ``.pt`` file when given a
cache folder, and :func:`hybrid_set` adds the classical estimate, so that the classical level can change
without rendering again.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import NamedTuple

import torch
import torch.nn.functional as F

from prismstereo.classical.defaults import default_hypotheses
from prismstereo.epipolar.sweep import depth_to_sweep
from prismstereo.errors import OptionError
from prismstereo.geometry.presets import thesis_setup1, thesis_setup2
from prismstereo.geometry.rig import BiPrismRig
from prismstereo.learned.data import KINDS, SEED_LIMIT, random_capture_spec
from prismstereo.learned.hybrid import HybridStereo
from prismstereo.synthetic import ImageFormation, Scene, height_field_scene, render

__all__ = ["HELD_OUT_PHOTOS", "TRAIN_PHOTOS", "HybridSet", "Rendered", "hybrid_set", "photo_scene", "photographs",
           "render_set", "training_rigs", "training_sets", "truth_sweep"]

TRAIN_PHOTOS: tuple[str, ...] = ("astronaut", "brick", "camera", "cat", "coffee", "coins", "grass", "gravel",
                                 "hubble_deep_field", "immunohistochemistry", "moon", "page", "retina", "rocket",
                                 "text", "cell", "clock")
HELD_OUT_PHOTOS: tuple[str, ...] = ("stereo_motorcycle",)  # evaluation only, with the Middlebury pairs


def photographs(names: tuple[str, ...] = TRAIN_PHOTOS) -> list[torch.Tensor]:
    """scikit-image's bundled photographs as grey (h, w) float32 tensors in [0, 1].

    Raises:
        OptionError: scikit-image is missing (``pip install prismstereo[fit]``) or a name it does not have.

    Example:
        >>> photographs(("camera",))[0].shape  # doctest: +SKIP
        torch.Size([512, 512])
    """
    try:
        import skimage.data
    except ImportError as exc:
        raise OptionError("the photographs need scikit-image: pip install prismstereo[fit]") from exc
    out = []
    for name in names:
        if name not in TRAIN_PHOTOS + HELD_OUT_PHOTOS or not hasattr(skimage.data, name):
            raise OptionError(f"Unknown photograph {name!r}. Choose from: {', '.join(TRAIN_PHOTOS)}")
        picture = getattr(skimage.data, name)()
        picture = picture[0] if isinstance(picture, tuple) else picture
        t = torch.from_numpy(picture).float()
        t = t[..., :3].mean(-1) if t.dim() == 3 else t
        out.append((t / t.max().clamp_min(1.0)).contiguous())
    return out


def training_rigs() -> list[tuple[str, BiPrismRig, tuple[float, float]]]:
    """The (name, rig, range) variants training renders through, all 1024 x 768.

    Example:
        >>> [name for name, _, _ in training_rigs()][:2]
        ['setup1', 'setup1 450-1000']
    """
    s1, s2 = thesis_setup1(), thesis_setup2()
    return [("setup1", s1, (228.0, 1374.0)), ("setup1 450-1000", s1, (450.0, 1000.0)),
            ("setup2", s2, (220.0, 1280.0)), ("setup2 300-900", s2, (300.0, 900.0)),
            ("alpha 8", s1.replace(alpha_deg=8.0), (250.0, 1200.0)),
            ("apex 130", s1.replace(apex_distance_mm=130.0), (200.0, 1000.0)),
            ("barrel", s1.replace(distortion=(-0.12, 0.0, 0.0, 0.0, 0.0)), (250.0, 1300.0))]


def _uniform(gen: torch.Generator, lo: float, hi: float) -> float:
    return lo + (hi - lo) * float(torch.rand(1, generator=gen))


def _smooth(x: torch.Tensor, sigma: float) -> torch.Tensor:
    r = max(1, int(3 * sigma))
    k = torch.exp(-torch.arange(-r, r + 1, dtype=x.dtype) ** 2 / (2 * sigma**2))
    k = k / k.sum()
    x = F.conv2d(F.pad(x[None, None], (r, r, 0, 0), mode="replicate"), k.view(1, 1, 1, -1))
    return F.conv2d(F.pad(x, (0, 0, r, r), mode="replicate"), k.view(1, 1, -1, 1))[0, 0]


def photo_scene(photo: torch.Tensor, gen: torch.Generator, z_range_mm: tuple[float, float]) -> Scene:
    """A random crop of ``photo`` (h, w) as a height field inside ``z_range_mm``: smooth relief, a slant, and up to
    three regions of the blurred photograph above a random level moved nearer (depth jumps along its edges).

    Example:
        >>> scene = photo_scene(torch.rand(200, 300), torch.Generator().manual_seed(0), (450.0, 900.0))
        >>> scene.surfaces[0].z_min >= 450.0
        True
    """
    lo, hi = z_range_mm
    h, w = photo.shape
    cw = int(min(w, max(96, _uniform(gen, 0.3, 1.0) * w)))
    ch = min(h, int(cw * 0.75))
    cw = int(ch / 0.75)
    r0, c0 = int(torch.randint(h - ch + 1, (1,), generator=gen)), int(torch.randint(w - cw + 1, (1,), generator=gen))
    picture = photo[r0:r0 + ch, c0:c0 + cw]
    if bool(torch.rand(1, generator=gen) < 0.5):
        picture = picture.flip(-1)
    size = (min(ch, 192), min(cw, 256))  # the renderer marches the field in steps of its texels
    picture = F.interpolate(picture[None, None], size=size, mode="area")[0, 0].clamp(0, 1)
    gy, gx = torch.meshgrid(torch.linspace(-1, 1, size[0]), torch.linspace(-1, 1, size[1]), indexing="ij")
    z = _uniform(gen, lo + 0.15 * (hi - lo), hi - 0.1 * (hi - lo))
    inv = 1.0 / z + (_uniform(gen, -0.15, 0.15) * gx + _uniform(gen, -0.1, 0.1) * gy) / z
    relief = torch.randn(1, 1, 4, 5, generator=gen)
    inv = inv + _uniform(gen, 0.0, 0.05) / z * F.interpolate(relief, size=size, mode="bicubic")[0, 0]
    blurred = _smooth(picture, _uniform(gen, 1.0, 4.0))
    for _ in range(int(torch.randint(4, (1,), generator=gen))):
        level = torch.quantile(blurred.flatten(), _uniform(gen, 0.5, 0.9))
        sign = 1 if bool(torch.rand(1, generator=gen) < 0.5) else -1
        region = (sign * (blurred - level) > 0).float()
        inv = inv + region * _uniform(gen, 0.03, 0.25) / z
    depth = (1.0 / inv).clamp(lo + 5, hi - 5)
    return height_field_scene(depth, picture, width_mm=float(depth.mean()) * _uniform(gen, 0.2, 0.3),
                              name=f"photo_{z:.0f}mm")


def _formation(gen: torch.Generator, z_range_mm: tuple[float, float], base: ImageFormation | None) -> ImageFormation:
    lo, hi = z_range_mm
    defocus = float(torch.rand(1, generator=gen)) < 0.2
    return dataclasses.replace(
        base or ImageFormation(supersample=1), noise_sigma=_uniform(gen, 0.5, 3.0) / 255,
        blur_sigma_px=_uniform(gen, 0.0, 1.2) if float(torch.rand(1, generator=gen)) < 0.5 else 0.0,
        f_number=_uniform(gen, 6.0, 16.0) if defocus else None, focus_mm=_uniform(gen, lo, hi),
        fresnel=float(torch.rand(1, generator=gen)) < 0.5, vignetting=_uniform(gen, 0.0, 0.4),
        seed=int(torch.randint(SEED_LIMIT, (1,), generator=gen)))


def _photometric(image: torch.Tensor, w_ref: int, gen: torch.Generator) -> torch.Tensor:
    """Gamma and a brightness ratio of the halves, re-quantised to 8 bits."""
    out = image.clamp(0, 1) ** _uniform(gen, 0.7, 1.4)
    out[..., w_ref:] = out[..., w_ref:] * _uniform(gen, 0.85, 1.15)
    return (out.clamp(0, 1) * 255).round() / 255


class Rendered(NamedTuple):
    """One rig variant's rendered captures on a b x b-binned grid (what the cache keeps; h, w the binned reference
    half, W2 the binned sensor width; b = 2 for the sensors the hybrid is trained on).

    Attributes:
        grey: (N, 1, h, W2) the binned grey captures (8-bit values in [0, 1]).
        truth: (N, 1, h, w) true sweep coordinate over the variant's range (the mean over each b x b block), NaN where
            unknown.
        known: (N, 1, h, w) bool, blocks the other half sees whose true depths agree within half a step.
        rays: (N, 1, h, w) bool, blocks with a true depth (the confidence's domain).
    """

    grey: torch.Tensor
    truth: torch.Tensor
    known: torch.Tensor
    rays: torch.Tensor


class HybridSet(NamedTuple):
    """One rig variant's training captures with the classical estimate the refinement starts from.

    Attributes:
        name, rig, z_range_mm: the variant.
        image: (N, 2, h, W2) normalised binned captures.
        s, confidence, covered: (N, 1, h, w) the classical estimate (:class:`~prismstereo.learned.hybrid.
            RefinementInputs`).
        truth, known, rays: :class:`Rendered`'s.
    """

    name: str
    rig: BiPrismRig
    z_range_mm: tuple[float, float]
    image: torch.Tensor
    s: torch.Tensor
    confidence: torch.Tensor
    covered: torch.Tensor
    truth: torch.Tensor
    known: torch.Tensor
    rays: torch.Tensor


def render_set(name: str, rig: BiPrismRig, z_range_mm: tuple[float, float], count: int, *, seed: int = 0,
               cache: str | Path | None = None, progress: bool = False, binning: int = 2) -> Rendered:
    """Render ``count`` captures through one rig variant (photographs and procedural kinds in turn), binned
    ``binning`` x ``binning`` (1 or 2: the hybrid's stage grid, :attr:`HybridStereo.binning`), or read them from
    ``cache``.

    Raises:
        OptionError: ``count`` < 1, ``binning`` not 1 or 2.

    Example:
        >>> rendered = render_set("small", thesis_setup1().downscaled(4), (450.0, 1000.0), 1)  # doctest: +SKIP
    """
    if isinstance(count, bool) or not isinstance(count, int) or count < 1:
        raise OptionError(f"count must be an int >= 1, got {count!r}")
    if isinstance(binning, bool) or binning not in (1, 2):
        raise OptionError(f"binning must be 1 or 2, got {binning!r}")
    path = None
    if cache is not None:
        key = f"{name}_{rig.image_width}x{rig.image_height}_{z_range_mm[0]:g}-{z_range_mm[1]:g}".replace(" ", "_")
        path = Path(cache) / f"rendered_{key}_{count}_{seed}{'' if binning == 2 else f'_b{binning}'}.pt"
        if path.is_file():
            blob = torch.load(path, weights_only=True)
            return Rendered(*(blob[k] for k in Rendered._fields))
    gen = torch.Generator().manual_seed(seed)
    photos = photographs()
    w_ref = rig.reference_width
    b = binning
    step = 2.0 / (default_hypotheses(rig.binned(b), z_range_mm) - 1)
    rows: dict[str, list[torch.Tensor]] = {k: [] for k in Rendered._fields}
    from tqdm.auto import tqdm

    for i in tqdm(range(count), desc=f"render {name}", disable=not progress):
        if i % 2 == 0:
            photo = photos[int(torch.randint(len(photos), (1,), generator=gen))]
            scene, formation = photo_scene(photo, gen, z_range_mm), _formation(gen, z_range_mm, None)
        else:
            scene, base = random_capture_spec(rig, gen, z_range_mm, KINDS[(i // 2) % len(KINDS)])
            formation = _formation(gen, z_range_mm, base)
        capture = render(rig, scene, formation)
        image = _photometric(capture.image.float().mean(1, keepdim=True), w_ref, gen)
        depth = capture.depth[..., :w_ref].float()
        truth = truth_sweep(depth, z_range_mm)
        h, w = depth.shape[-2] // b, depth.shape[-1] // b
        block = F.unfold(torch.nan_to_num(truth, nan=1e3), b, stride=b).view(1, b * b, h, w)
        seen = F.avg_pool2d(capture.covisible[..., :w_ref].float(), b) > 0.99
        finite = F.avg_pool2d(torch.isfinite(depth).float(), b) > 0.99
        known = seen & finite & ((block.amax(1, keepdim=True) - block.amin(1, keepdim=True)) < 0.5 * step)
        mean = block.mean(1, keepdim=True)
        for key, value in (("grey", F.avg_pool2d(image, b)), ("truth", torch.where(finite, mean, math.nan)),
                           ("known", known), ("rays", finite)):
            rows[key].append(value)
    data = Rendered(*(torch.cat(rows[k]) for k in Rendered._fields))
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        torch.save(data._asdict(), path)
    return data


def hybrid_set(name: str, rig: BiPrismRig, z_range_mm: tuple[float, float], count: int, *, seed: int = 0,
               model: HybridStereo | None = None, cache: str | Path | None = None,
               progress: bool = False) -> HybridSet:
    """:func:`render_set`'s captures with the classical estimate of ``model`` (a :class:`HybridStereo` of that rig and
    range; built when None), computed here, so that the classical level can change without
    rendering again.

    Raises:
        OptionError: ``count`` < 1.

    Example:
        >>> data = hybrid_set("small", thesis_setup1().downscaled(4), (450.0, 1000.0), 1)  # doctest: +SKIP
    """
    model = model or HybridStereo(rig, z_range_mm, weights=None)
    rendered = render_set(name, rig, z_range_mm, count, seed=seed, cache=cache, progress=progress,
                          binning=model.binning)
    with torch.no_grad():
        parts = [model.initial_binned(chunk) for chunk in rendered.grey.split(8)]
    image, s, confidence, covered = (torch.cat(t) for t in zip(*parts, strict=True))
    return HybridSet(name, rig, z_range_mm, image, s, confidence, covered, *rendered[1:])


def training_sets(captures: int, *, seed: int = 0, variants: list[int] | None = None, cache: str | Path | None = None,
                  models: list[HybridStereo] | None = None, progress: bool = False) -> list[HybridSet]:
    """:func:`hybrid_set` of every :func:`training_rigs` variant (or those numbered in ``variants``), ``captures``
    each, variant i seeded by ``seed`` * 100 + i (so that separate processes can render variants into one cache).

    Example:
        >>> sets = training_sets(24, variants=[0], cache=".cache/hybrid")  # doctest: +SKIP
    """
    rigs = training_rigs()
    chosen = range(len(rigs)) if variants is None else variants
    return [hybrid_set(*rigs[i], captures, seed=seed * 100 + i, cache=cache, progress=progress,
                       model=None if models is None else models[i]) for i in chosen]


def truth_sweep(depth: torch.Tensor, z_range_mm: tuple[float, float]) -> torch.Tensor:
    """The sweep coordinate of true depths (mm, NaN where unknown) over a range (NaN stays NaN).

    Example:
        >>> truth_sweep(torch.tensor([450.0, float("nan")]), (450.0, 900.0))
        tensor([-1., nan])
    """
    return depth_to_sweep(depth, torch.tensor(z_range_mm, dtype=depth.dtype, device=depth.device))
