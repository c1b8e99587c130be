"""``PrismStereo``: one bi-prism capture in, metric depth of the reference (left) half out.

The model composes :class:`~prismstereo.classical.level.DepthLevel` s, each the whole chain at one resolution: the
capture split at the apex column; a coarse search over the whole range on the exact sweep m(u, v, s) (s linear in
1/Z; :mod:`prismstereo.matching.search`, rectified shift volume or exact per-pixel sweep), whose estimate places a
band of 2 R + 1 hypotheses per pixel at full resolution (:mod:`prismstereo.matching.band`); the smoothing of the
estimate, depth from s (exact), the calibrated confidence, validity and the z-buffer occlusion test. One level, or a
pyramid: the level of the k x k-binned capture places the band of the full-resolution level (the default on sensors
whose reference half is >= 384 px on its shorter side).

Every option left None in the config is picked by one function, :func:`~prismstereo.classical.defaults.resolve_config`.
The chain stage by stage, why each default, and the command that measures it: ``docs/design.md``.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, NamedTuple

import torch
import torch.nn.functional as F
from torch import nn

from prismstereo.classical.config import StereoConfig, as_config
from prismstereo.classical.defaults import resolve_config
from prismstereo.classical.level import DepthLevel
from prismstereo.classical.prior import TemporalOptions
from prismstereo.classical.temporal import TemporalDepth, supports_temporal
from prismstereo.conventions import to_grey
from prismstereo.depth.bad_pixels import BAD_PIXEL_REACH, BadPixels, discard
from prismstereo.depth.resample import upsample
from prismstereo.depth.result import DepthResult
from prismstereo.epipolar.sweep import sweep_to_depth
from prismstereo.errors import OptionError, ShapeError, check_shape
from prismstereo.geometry.optics import check_rig_images
from prismstereo.geometry.rig import BiPrismRig
from prismstereo.runtime import tracing
from prismstereo.threads import per_image

__all__ = ["BlockEstimate", "ConfidenceInputs", "PrismStereo"]


class ConfidenceInputs(NamedTuple):
    """:meth:`PrismStereo.confidence_inputs`' result.

    Attributes:
        features: (B, 6, H, W_ref) :func:`~prismstereo.matching.confidence.confidence_features`.
        depth: (B, 1, H, W_ref) the depth (mm) they describe.
        sampled: (B, 1, H, W_ref) bool, pixels with an estimate (the confidence applies there).
        smoothed_features: (B, 4, H, W_ref) :func:`~prismstereo.matching.confidence.smoothed_features` of the
            smoothed estimate (``smoothing`` > 0), else None.
        smoothed_depth: (B, 1, H, W_ref) the depth (mm) after smoothing (what they describe), else None.
    """

    features: torch.Tensor
    depth: torch.Tensor
    sampled: torch.Tensor
    smoothed_features: torch.Tensor | None = None
    smoothed_depth: torch.Tensor | None = None


class BlockEstimate(NamedTuple):
    """:meth:`PrismStereo.block_estimate`'s result, (B, 1, h, w) maps on the block grid.

    Attributes:
        s: the sweep coordinate in [-1, 1] where covered, else 0.
        confidence: its confidence, 0 where not covered.
        covered: bool, the blocks with a depth (a dense model's: every block its band could sample).
    """

    s: torch.Tensor
    confidence: torch.Tensor
    covered: torch.Tensor


class PrismStereo(nn.Module):
    """Depth from one bi-prism capture: exact plane sweep, coarse-to-fine (the chain: the module docstring).

    Args:
        rig: the rig; its geometry is checked first (:func:`~prismstereo.geometry.optics.check_rig_images`:
            :class:`~prismstereo.errors.RigError` if a half-image sees nothing through the prism).
        z_range: (z_min, z_max) depth range searched, mm; default
            :func:`~prismstereo.depth.range.default_z_range` (from the rig's common field of view).
        config: the options: a :class:`~prismstereo.classical.config.StereoConfig` (every option, grouped by stage and
            documented there), a preset's name ('accurate' = None, 'fast', 'dense', 'reference';
            :data:`~prismstereo.classical.config.PRESETS`) or a dict of options on top of the default
            (``{"coarse_factor": 1}``); the options left None are picked by
            :func:`~prismstereo.classical.defaults.resolve_config`.

    Attributes:
        levels: the :class:`~prismstereo.classical.level.DepthLevel` s, coarsest first: one, or a pyramid's binned
            level and full-resolution level.
        resolved: the :class:`~prismstereo.classical.defaults.ResolvedConfig` the levels were built from.
        rig, downsample: the sensor's rig and the binning k of the first level.

    The learned model is :class:`~prismstereo.learned.LearnedStereo`, with the same :class:`DepthResult` output.

    Example:
        >>> small = thesis_setup1().downscaled(8)
        >>> model = PrismStereo(small, (400.0, 700.0), "fast")
        >>> model(torch.rand(1, 1, 96, 128)).depth.shape
        torch.Size([1, 1, 96, 64])
    """

    kind = "classical"

    def __init__(self, rig: BiPrismRig, z_range: tuple[float, float] | None = None,
                 config: StereoConfig | str | Mapping[str, Any] | None = None) -> None:
        super().__init__()
        check_rig_images(rig)  # the rig's geometry, before anything traces it
        self.resolved = resolved = resolve_config(rig, z_range, as_config(config))
        k, z_range = resolved.downsample, resolved.z_range_mm
        self.rig, self.downsample = rig, k
        if resolved.full_band:  # a pyramid: the binned level places a band of 2 full_band + 1 hypotheses
            binned_config, final_config = resolved.levels
            self.levels = nn.ModuleList([DepthLevel(rig.binned(k), z_range, binned_config),
                                         DepthLevel(rig, z_range, final_config, placed_by=k)])
        else:  # one level, on the capture binned by k (block values) or at full resolution
            self.levels = nn.ModuleList([DepthLevel(rig.binned(k) if k > 1 else rig, z_range, resolved.levels[0])])
        self.bad_pixels = BadPixels(rig, self.z_range, radius=BAD_PIXEL_REACH * k)

    @property
    def config(self) -> StereoConfig:
        """The options as asked, with the model-wide choices (``downsample``, ``full_band``) set:
        ``PrismStereo(model.rig, model.z_range, model.config)`` rebuilds the model (each level's own resolved
        options: ``model.levels[i].config``).

        Example:
            >>> model = PrismStereo(thesis_setup1().downscaled(8), (400.0, 700.0))
            >>> PrismStereo(model.rig, model.z_range, model.config).summary() == model.summary()
            True
        """
        return self.resolved.config

    @property
    def binned(self) -> DepthLevel | None:
        """A pyramid's binned level (it places the full-resolution band), else None."""
        return self.levels[0] if len(self.levels) > 1 else None

    @property
    def final(self) -> DepthLevel:
        """The level whose estimate is the depth (full resolution, or binned by ``downsample`` in block mode)."""
        return self.levels[-1]

    @property
    def z_range(self) -> tuple[float, float]:
        """(z_min, z_max) searched, mm."""
        return self.final.z_range

    @property
    def num_hypotheses(self) -> int:
        """D of the final level's sweep (uniform in 1/Z)."""
        return self.final.num_hypotheses

    @property
    def depths(self) -> torch.Tensor:
        """(D,) the final level's hypotheses, mm."""
        return self.final.depths

    @property
    def split(self) -> nn.Module:
        """The final level's :class:`~prismstereo.matching.split.SplitImage`."""
        return self.final.split

    @property
    def step(self) -> float:
        """The final level's hypothesis spacing in the sweep coordinate s (``index`` * step - 1 = s)."""
        return self.final.step

    def tracker(self, options: TemporalOptions | None = None) -> TemporalDepth | None:
        """The temporal band that tracks this model's depth through a video (:class:`~prismstereo.classical.temporal.
        TemporalDepth`: its full-resolution band placed on the previous frame), or None for a model without such a
        band (a single full-range level, block mode).

        Example:
            >>> model = PrismStereo(thesis_setup1().downscaled(8), (400.0, 700.0), {"coarse_factor": 2})
            >>> type(model.tracker()).__name__, PrismStereo(model.rig, (400.0, 700.0)).tracker()
            ('TemporalDepth', None)
        """
        return TemporalDepth(self, options) if supports_temporal(self) else None

    def block_estimate(self, binned: torch.Tensor) -> BlockEstimate:
        """Block mode's estimate on its own grid: the sweep coordinate, confidence and coverage of a capture already
        binned by ``downsample`` (what :class:`~prismstereo.learned.HybridStereo` refines).

        Args:
            binned: (B, C, H / k, W / k) the capture box-averaged over k x k blocks (k = ``downsample``).

        Returns:
            BlockEstimate of (B, 1, H / k, W_ref / k) maps.

        Raises:
            OptionError: a model that is not in block mode (``downsample`` > 1 and ``full_band`` 0).

        Example:
            >>> model = PrismStereo(thesis_setup1().downscaled(4), (450.0, 900.0), {"downsample": 2, "full_band": 0})
            >>> model.block_estimate(torch.rand(1, 1, 96, 128)).s.shape
            torch.Size([1, 1, 96, 64])
        """
        if self.downsample == 1 or self.binned is not None:
            raise OptionError("block_estimate needs block mode (downsample > 1, full_band 0)")
        res = self.final.depth(binned)
        covered = res.confidence > 0
        s = torch.where(covered, res.index * self.final.step - 1.0, torch.zeros_like(res.index))
        return BlockEstimate(s, res.confidence, covered)

    def describe(self) -> dict[str, Any]:
        """What the model is, JSON-ready (the ONNX export's metadata and cache key): its class, range, hypotheses
        and options.

        Example:
            >>> PrismStereo(thesis_setup1().downscaled(8), (400.0, 700.0)).describe()["num_hypotheses"]
            15
        """
        return {"model": "PrismStereo", "z_range_mm": list(self.z_range), "num_hypotheses": self.num_hypotheses,
                "config": self.config.to_dict()}

    def summary(self) -> str:
        """The model's levels in one line (for logs, the CLI and the benchmarks).

        Example:
            >>> PrismStereo(thesis_setup1().downscaled(8), (400.0, 700.0)).summary()
            '15 hypotheses in one level'
            >>> PrismStereo(thesis_setup1(), (228.0, 1374.0)).summary()
            '2x2-binned model (192 hypotheses, ... +-3), then a full-resolution band +-2 of 382, band edges clamped'
        """
        k, final = self.downsample, self.final
        has_band = self.binned is not None or final.factor > 1  # a single level has no band to clamp
        edges = ", band edges clamped" if final.config.search.band_edges == "clamp" and has_band else ""
        if self.binned is not None:
            return (f"{k}x{k}-binned model ({self.binned.summary()}), then a full-resolution band +-{final.band} of "
                    f"{final.num_hypotheses}{edges}")
        return final.summary() + (f", on {k}x{k}-binned pixels" if k > 1 else "") + edges

    def forward(self, image: torch.Tensor) -> DepthResult:
        """Depth of the reference half of ``image`` (B, C, H, W) in [0, 1], C = 1 or 3 (colour: its
        :func:`~prismstereo.conventions.to_grey`); a :class:`DepthResult` of (B, *, H, W_ref) tensors.

        In torch eager a batch is evaluated image by image on worker threads, each with a share of the caller's
        intra-op threads and its grad / inference mode (:func:`~prismstereo.threads.per_image`); traced or exported
        it is one graph for the whole batch.
        """
        check_shape(image, ["B", "C", "H", "W"], "image")
        image, touched = self.bad_pixels(image)
        image = to_grey(image)  # the one grey rule: a colour capture and its grey give the same depth
        if image.shape[0] > 1 and not tracing():
            parts = per_image(self._forward, image)
            return discard(DepthResult(*(torch.cat(ts, 0) for ts in zip(*parts, strict=True))), touched)
        return discard(self._forward(image), touched)

    def _placement(self, image: torch.Tensor):
        """The pyramid's binned level's placement of the final band (None for one level)."""
        if self.binned is None:
            return None
        with torch.no_grad():  # it only places the band
            return self.binned.placement(F.avg_pool2d(image, self.downsample))

    def _forward(self, image: torch.Tensor) -> DepthResult:
        k = self.downsample
        if k == 1:
            return self.final.depth(image)
        h, w = self.rig.image_height, self.rig.image_width
        if image.shape[-2:] != (h, w):
            raise ShapeError(f"image is {image.shape[-1]}x{image.shape[-2]} px but the rig's sensor is {w}x{h}")
        if self.binned is not None:
            return self.final.depth(image, self._placement(image))
        res = self.final.depth(F.avg_pool2d(image, k))  # drops the last H mod k rows / W mod k columns, as binned()
        w_ref = self.rig.reference_width

        def up(t: torch.Tensor) -> torch.Tensor:  # nearest: each pixel gets its block's value; 0 beyond
            return upsample(t, k, (h, w_ref), beyond="zero")

        match = res.match * k + (k - 1) / 2  # binned -> full-sensor pixels (block centres)
        valid = up(res.valid.to(res.depth.dtype)) > 0.5
        return DepthResult(up(res.depth), valid, up(res.confidence), up(res.index), up(match))

    def confidence_inputs(self, image: torch.Tensor) -> ConfidenceInputs:
        """What the calibrated confidence sees: the features (:data:`~prismstereo.matching.confidence.FEATURES`)
        of every pixel of ``image`` (B, C, H, W) with the depth they describe, for fitting a confidence to a
        rig or a kind of scene (:func:`~prismstereo.matching.confidence.fit_confidence`,
        ``benchmarks/fit_confidence.py``). Needs ``validity='calibrated'``.

        Example:
            >>> model = PrismStereo(thesis_setup1().downscaled(4), (400.0, 700.0), {"coarse_factor": 2})
            >>> model.confidence_inputs(torch.rand(1, 1, 192, 256)).features.shape
            torch.Size([1, 6, 192, 128])
        """
        final = self.final
        if final.calibration is None:
            raise OptionError("confidence_inputs needs validity='calibrated'")
        check_shape(image, ["B", "C", "H", "W"], "image")
        image = to_grey(image)
        if self.downsample > 1 and self.binned is None:
            raise OptionError("confidence_inputs needs the full-resolution model (downsample 1 or a pyramid)")
        est = final.estimate(image, self._placement(image))
        z_range = torch.tensor(self.z_range, dtype=est.s.dtype, device=est.s.device)
        s = est.s.clamp(-1.0, 1.0)
        sampled = est.ok & final.reference_valid
        if not final.config.refinement.smoothing:
            return ConfidenceInputs(est.features, sweep_to_depth(s, z_range), sampled)
        smoothed, _, features = final.smooth(s, est.confidence, est.sampled)
        return ConfidenceInputs(est.features, sweep_to_depth(s, z_range), sampled, features,
                                sweep_to_depth(smoothed, z_range))

