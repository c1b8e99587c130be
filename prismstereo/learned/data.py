"""Random training captures with exact ground truth, rendered by :mod:`prismstereo.synthetic`.

Scenes: fronto-parallel and slanted planes, depth steps, spheres before a plane and smooth height fields whose
procedural picture is strongly textured in some regions and nearly flat in others (as the confidence fit of
``benchmarks/fit_confidence.py`` makes them). Noise textures have features of 1-8 px and contrasts from
nearly none to strong; the image formation varies read noise (0.5-3 grey levels), Gaussian blur (0-1.5 px), and
sometimes adds thin-lens defocus and the prism's Fresnel transmission. Every depth lies in the given range.

Texture seeds are drawn below 9000: seeds >= 9000 and the Middlebury photographs are kept for evaluation.
Rendering dominates the cost, so :func:`training_set` keeps its result in a ``.pt`` file when given a cache
folder.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import NamedTuple

import torch
import torch.nn.functional as F

from prismstereo.errors import OptionError
from prismstereo.geometry.rig import BiPrismRig
from prismstereo.synthetic import (
    ImageFormation,
    NoiseTexture,
    Scene,
    feature_size_for_depth,
    fronto_parallel_plane,
    height_field_scene,
    render,
    slanted_plane,
    sphere_scene,
    step_scene,
)

__all__ = ["KINDS", "SEED_LIMIT", "TrainingSet", "procedural_picture", "random_capture_spec", "training_set"]

KINDS: tuple[str, ...] = ("plane", "slanted", "step", "sphere", "surface")
SEED_LIMIT = 9000  # texture seeds stay below: >= 9000 is held out for evaluation


class TrainingSet(NamedTuple):
    """N rendered captures, the reference half's ground truth only.

    Attributes:
        image: (N, 1, H, W) float32 in [0, 1], the whole capture.
        depth: (N, 1, H, W_ref) float32 true Z (mm), NaN where the pixel sees nothing.
        covisible: (N, 1, H, W_ref) bool, reference pixels whose point the right half sees unoccluded.
        names: N scene names.
    """

    image: torch.Tensor
    depth: torch.Tensor
    covisible: torch.Tensor
    names: list[str]


def _uniform(gen: torch.Generator, lo: float, hi: float) -> float:
    return lo + (hi - lo) * float(torch.rand(1, generator=gen))


def _smooth_noise(gen: torch.Generator, h: int, w: int, cell: int) -> torch.Tensor:
    g = torch.randn(1, 1, h // cell + 3, w // cell + 3, generator=gen)
    return F.interpolate(g, size=(h, w), mode="bicubic", align_corners=False)[0, 0]


def procedural_picture(gen: torch.Generator, h: int = 240, w: int = 320) -> tuple[torch.Tensor, torch.Tensor]:
    """A weakly textured picture and smooth bumps, (h, w) each.

    The picture is slow shading plus fine noise whose contrast varies over the picture from 0.01 (almost no
    texture) to 0.21; the bumps are four random Gaussians of unit scale.

    Example:
        >>> picture, bumps = procedural_picture(torch.Generator().manual_seed(0), 60, 80)
        >>> picture.shape, bool(picture.min() >= 0), bumps.shape
        (torch.Size([60, 80]), True, torch.Size([60, 80]))
    """
    fine = sum(0.5**k * _smooth_noise(gen, h, w, 2 * 2**k) for k in range(3))
    fine = fine / fine.std()
    contrast = 0.01 + 0.2 * torch.sigmoid(3 * _smooth_noise(gen, h, w, max(h // 6, 2)))
    picture = (0.5 + 0.15 * _smooth_noise(gen, h, w, max(h // 3, 2)) + contrast * fine).clamp(0, 1)
    yy, xx = torch.meshgrid(torch.linspace(0, 1, h), torch.linspace(0, 1, w), indexing="ij")
    bumps = torch.zeros(h, w)
    for _ in range(4):
        cy, cx = torch.rand(2, generator=gen).tolist()
        r = 0.1 + 0.25 * float(torch.rand(1, generator=gen))
        bumps += float(torch.randn(1, generator=gen)) * torch.exp(-((yy - cy) ** 2 + (xx - cx) ** 2) / (2 * r * r))
    return picture, bumps


def _retexture(scene: Scene, rig: BiPrismRig, gen: torch.Generator, texel_px: float) -> Scene:
    """Give every surface a noise texture of random contrast (weak on a quarter of them)."""
    for surface in scene.surfaces:
        weak = float(torch.rand(1, generator=gen)) < 0.25
        contrast = math.exp(_uniform(gen, math.log(0.01), math.log(0.04)) if weak else
                            _uniform(gen, math.log(0.04), math.log(0.3)))
        seed = int(torch.randint(SEED_LIMIT, (1,), generator=gen))
        feature = feature_size_for_depth(rig, surface.nearest_depth(), texel_px)
        surface.texture = NoiseTexture(feature, seed=seed, contrast=contrast)
    return scene


def random_capture_spec(
    rig: BiPrismRig, gen: torch.Generator, z_range_mm: tuple[float, float], kind: str
) -> tuple[Scene, ImageFormation]:
    """One random scene of ``kind`` (one of :data:`KINDS`) within ``z_range_mm`` and its image formation.

    Example:
        >>> rig = thesis_setup1().downscaled(8)
        >>> scene, formation = random_capture_spec(rig, torch.Generator().manual_seed(0), (450.0, 1000.0), "step")
        >>> len(scene.surfaces), formation.supersample
        (2, 2)
    """
    if kind not in KINDS:
        raise OptionError(f"Unknown kind {kind!r}. Choose from: {', '.join(map(repr, KINDS))}")
    lo, hi = z_range_mm
    texel = math.exp(_uniform(gen, 0.0, math.log(8.0)))
    seed = int(torch.randint(SEED_LIMIT, (1,), generator=gen))
    if kind == "plane":
        scene = _retexture(fronto_parallel_plane(rig, _uniform(gen, lo + 5, hi - 5), seed, 1, texel), rig, gen, texel)
    elif kind == "slanted":
        z = _uniform(gen, lo + 0.1 * (hi - lo), hi - 0.1 * (hi - lo))
        scene = slanted_plane(rig, z, _uniform(gen, -35, 35), _uniform(gen, -20, 20), seed, 1, texel)
        scene = _retexture(scene, rig, gen, texel)
    elif kind == "step":
        near = _uniform(gen, lo + 5, hi - 60)
        far = _uniform(gen, near + 40, min(hi - 5, near + 300))
        scene = step_scene(rig, near, far, _uniform(gen, -30, 30), ("left", "right")[int(torch.randint(2, (1,),
                           generator=gen))], seed, 1, texel)
        scene = _retexture(scene, rig, gen, texel)
    elif kind == "sphere":
        radius = _uniform(gen, 15, 60)
        centre = _uniform(gen, lo + radius + 5, hi - radius - 40)
        back = _uniform(gen, centre + radius + 20, hi - 5)
        scene = _retexture(sphere_scene(rig, centre, radius, back, seed, 1, texel), rig, gen, texel)
    else:
        picture, bumps = procedural_picture(gen, 120, 160)  # coarse: the renderer marches in steps of a texel
        z = _uniform(gen, lo + 60, hi - 60)
        amplitude = _uniform(gen, 0.02, 0.06) * z
        depth = (z + amplitude * bumps.clamp(-1.3, 1.3)).clamp(lo + 5, hi - 5)
        scene = height_field_scene(depth, picture, width_mm=z * 0.21, name=f"surface_{z:.0f}mm")
    defocus = float(torch.rand(1, generator=gen)) < 1 / 6
    formation = ImageFormation(
        supersample=1 if kind == "surface" else 2,  # height fields are ray-marched: one sample per pixel
        noise_sigma=_uniform(gen, 0.5, 3.0) / 255,
        blur_sigma_px=_uniform(gen, 0.0, 1.5) if float(torch.rand(1, generator=gen)) < 0.6 else 0.0,
        f_number=_uniform(gen, 8.0, 16.0) if defocus else None,
        focus_mm=_uniform(gen, lo, hi),
        fresnel=float(torch.rand(1, generator=gen)) < 0.5,
        seed=int(torch.randint(SEED_LIMIT, (1,), generator=gen)),
    )
    return scene, formation


def training_set(
    rig: BiPrismRig,
    count: int,
    *,
    seed: int = 0,
    z_range_mm: tuple[float, float] = (450.0, 1000.0),
    cache: str | Path | None = None,
    progress: bool = False,
) -> TrainingSet:
    """Render ``count`` random captures (scene kinds in turn, see :data:`KINDS`), or read them from ``cache``.

    Args:
        rig: the rig rendered through (training uses a small one, e.g. ``thesis_setup1().downscaled(2)``).
        count: number of captures (>= 1).
        seed: seeds the scene and formation draws (same seed, same set).
        z_range_mm: every scene depth lies inside.
        cache: a folder: the set is stored there as ``train_<W>x<H>_<count>_<seed>_<zmin>-<zmax>.pt`` and read
            back when present.
        progress: a progress bar over the renders.

    Returns:
        TrainingSet.

    Raises:
        OptionError: ``count`` < 1 or a range that is not increasing.

    Example:
        >>> data = training_set(thesis_setup1().downscaled(16), 2)
        >>> data.image.shape, data.depth.shape, data.covisible.dtype
        (torch.Size([2, 1, 48, 64]), torch.Size([2, 1, 48, 32]), torch.bool)
    """
    if isinstance(count, bool) or not isinstance(count, int) or count < 1:
        raise OptionError(f"count must be an int >= 1, got {count!r}")
    lo, hi = (float(z) for z in z_range_mm)
    if not 0 < lo < hi:
        raise OptionError(f"z_range_mm must be increasing and positive, got {z_range_mm}")
    path = None
    if cache is not None:
        path = Path(cache) / f"train_{rig.image_width}x{rig.image_height}_{count}_{seed}_{lo:g}-{hi:g}.pt"
        if path.is_file():
            blob = torch.load(path, weights_only=True)
            return TrainingSet(blob["image"], blob["depth"], blob["covisible"], list(blob["names"]))
    gen = torch.Generator().manual_seed(seed)
    w_ref = rig.reference_width
    images, depths, covisible, names = [], [], [], []
    from tqdm.auto import tqdm

    for i in tqdm(range(count), desc="render", disable=not progress):
        scene, formation = random_capture_spec(rig, gen, (lo, hi), KINDS[i % len(KINDS)])
        cap = render(rig, scene, formation)
        images.append(cap.image.float())
        depths.append(cap.depth[..., :w_ref].float())
        covisible.append(cap.covisible[..., :w_ref])
        names.append(scene.name)
    data = TrainingSet(torch.cat(images), torch.cat(depths), torch.cat(covisible), names)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        torch.save(data._asdict(), path)
    return data
