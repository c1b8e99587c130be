"""``PrismStereo``: one bi-prism capture in, metric depth of the reference (left) half out.

The model composes :class:`~prismstereo.depth.level.DepthLevel` s, each the whole chain at one resolution: the
capture split at the apex column; a coarse search over the whole range on the exact sweep m(u, v, s) (s linear in
1/Z; :mod:`prismstereo.matching.search`, rectified shift volume or exact per-pixel sweep), whose estimate places a
band of 2 R + 1 hypotheses per pixel at full resolution (:mod:`prismstereo.matching.band`); the smoothing of the
estimate, depth from s (exact), the calibrated confidence, validity and the z-buffer occlusion test. One level, or a
pyramid: the level of the k x k-binned capture places the band of the full-resolution level (the default on sensors
whose reference half is >= 384 px on its shorter side).

Every option left None in the config is picked by one function, :func:`~prismstereo.defaults.resolve_config`. The
chain stage by stage, why each default, and the command that measures it: ``docs/design.md``.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, NamedTuple

import torch
import torch.nn.functional as F
from torch import nn

from prismstereo.config import StereoConfig, as_config
from prismstereo.defaults import resolve_config
from prismstereo.depth.level import DepthLevel, upsample
from prismstereo.depth.result import DepthResult
from prismstereo.epipolar.sweep import sweep_to_depth
from prismstereo.errors import OptionError, ShapeError, check_shape
from prismstereo.geometry.optics import check_rig_images
from prismstereo.geometry.rig import BiPrismRig
from prismstereo.runtime import tracing
from prismstereo.threads import per_image

__all__ = ["ConfidenceInputs", "DepthResult", "PrismStereo"]


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


class PrismStereo(nn.Module):
    """Depth from one bi-prism capture: exact plane sweep, coarse-to-fine (the chain: the module docstring).

    Args:
        rig: the rig; its geometry is checked first (:func:`~prismstereo.geometry.optics.check_rig_images`:
            :class:`~prismstereo.errors.RigError` if a half-image sees nothing through the prism).
        z_range_mm: (z_min, z_max) depth range searched; default
            :func:`~prismstereo.depth.range.default_z_range` (from the rig's common field of view).
        config: the options: a :class:`~prismstereo.config.StereoConfig` (every option, grouped by stage and
            documented there), a preset's name ('accurate' = None, 'fast', 'dense', 'reference';
            :data:`~prismstereo.config.PRESETS`) or a dict of options on top of the default
            (``{"coarse_factor": 1}``); the options left None are picked by
            :func:`~prismstereo.defaults.resolve_config`.

    Attributes:
        levels: the :class:`~prismstereo.depth.level.DepthLevel` s, coarsest first: one, or a pyramid's binned
            level and full-resolution level.
        resolved: the :class:`~prismstereo.defaults.ResolvedConfig` the levels were built from.
        rig, downsample: the sensor's rig and the binning k of the first level.

    The learned model is :class:`~prismstereo.learned.LearnedStereo`, with the same :class:`DepthResult` output.

    Example:
        >>> small = thesis_setup1().downscaled(8)
        >>> model = PrismStereo(small, (400.0, 700.0), "fast")
        >>> model(torch.rand(1, 1, 96, 128)).depth.shape
        torch.Size([1, 1, 96, 64])
    """

    def __init__(self, rig: BiPrismRig, z_range_mm: tuple[float, float] | None = None,
                 config: StereoConfig | str | Mapping[str, Any] | None = None) -> None:
        super().__init__()
        check_rig_images(rig)  # the rig's geometry, before anything traces it
        self.resolved = resolved = resolve_config(rig, z_range_mm, as_config(config))
        k, z_range = resolved.downsample, resolved.z_range_mm
        self.rig, self.downsample = rig, k
        if resolved.full_band:  # a pyramid: the binned level places a band of 2 full_band + 1 hypotheses
            binned_config, final_config = resolved.levels
            self.levels = nn.ModuleList([DepthLevel(rig.binned(k), z_range, binned_config),
                                         DepthLevel(rig, z_range, final_config, placed_by=k)])
        else:  # one level, on the capture binned by k (block values) or at full resolution
            self.levels = nn.ModuleList([DepthLevel(rig.binned(k) if k > 1 else rig, z_range, resolved.levels[0])])

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
        """Depth of the reference half of ``image`` (B, C, H, W) in [0, 1], C = 1 or 3; a
        :class:`DepthResult` of (B, *, H, W_ref) tensors.

        In torch eager a batch is evaluated image by image on worker threads, each with a share of the caller's
        intra-op threads and its grad / inference mode (:func:`~prismstereo.threads.per_image`); traced or exported
        it is one graph for the whole batch.
        """
        check_shape(image, ["B", "C", "H", "W"], "image")
        if image.shape[0] > 1 and not tracing():
            parts = per_image(self._forward, image)
            return DepthResult(*(torch.cat(ts, 0) for ts in zip(*parts, strict=True)))
        return self._forward(image)

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

