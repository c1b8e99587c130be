"""HybridStereo: a first stage on the exact sweep at a coarse level, then a learned image-guided 2-D refinement and the
exact classical band.

Data path (one capture, both halves as recorded). The stages work on a b x b-binned grid, b = 2 where the classical
default fits its band on the 2 x 2-binned grid (:func:`~prismstereo.classical.defaults.default_downsample`: reference
half >= 384 px on its shorter side), else 1: a surface covers about as many of its pixels on every sensor. (h, w) is
the reference half on that grid, k = ``block`` * b / 2 the classical level's binning:

1. the first stage (``HybridArchitecture.start``): ``'learned'`` (the default;
   :class:`~prismstereo.learned.sweep_start.SweepStart`: learned features correlated along the exact sweep over the
   whole range on 4 x 4 cells of the stages' grid, aggregated on those cells pooled 2 x 2, 4 x 4 and 8 x 8, its s and
   confidence carried to the 2b x 2b-binned grid bilinearly), or ``'classical'``:
   :class:`~prismstereo.classical.model.PrismStereo` in block mode (``downsample`` k, no full-resolution band) with the
   'dense' preset (:func:`~prismstereo.learned.refinement.classical_config`): the exact plane sweep on the k x k-binned
   capture gives every covered block a sweep coordinate s (linear in 1/Z), its calibrated confidence and the coverage
   (:meth:`~prismstereo.classical.model.PrismStereo.block_estimate`);
2. refinement stages, first on that grid (``quarter``, block 4: the 2b x 2b-binned grid, twice the reach per layer),
   then on the stages' grid (``iterations``; the maps carried over bilinearly, block centres kept: pixel j of a
   b x b-binned grid is at full-sensor b j + (b - 1) / 2). Each samples the other half of the normalised capture
   (:func:`~prismstereo.learned.network.normalise_image`) along every reference pixel's exact sweep (the binned
   rig's sweep polynomials, thesis eq. 4.1-4.10 done exactly: :func:`sweep_match`) at s + o steps for offsets
   o = -2 ... 2 (a step is <= 1 px at the stage's resolution:
   :func:`~prismstereo.classical.defaults.default_hypotheses`); the local absolute differences are a small cost curve
   around the estimate. A dilated 3 x 3 CNN (the StereoNet / HITNet refinement) on the reference image, the cost curve,
   the estimate's local relief and the classical confidence and coverage predicts a residual of s in steps and a
   confidence logit;
3. the exact last stage (``last_stage='exact'``, the default; :mod:`~prismstereo.learned.exact_stage`): the
   classical band's fit on the exact sweep around the estimate, on the stages' grid, replaces the estimate where it
   is valid and agrees with it (a regressed estimate carries a smooth bias of a tenth of a step on textured
   surfaces, the smoothed fit does not). Where the weights hold a confidence head
   (:mod:`~prismstereo.learned.exact_confidence`), it re-scores the learned confidence with what the band found;
   else the confidence is the learned one;
4. s and the confidence bilinearly to full resolution (b = 2), depth exact from s (thesis eq. 6.1-6.10 via the
   sweep).

The weights are the CNNs only; the sweep, masks and the classical level are built from the rig and range the model
is constructed with, so the same weights run on any rig whose sensor the block divides.
"""

from __future__ import annotations

import dataclasses
import hashlib
from pathlib import Path
from typing import Any, Literal

import torch
import torch.nn.functional as F
from torch import nn

from prismstereo.classical import PrismStereo, TemporalDepth, TemporalOptions
from prismstereo.classical.defaults import default_downsample, default_hypotheses
from prismstereo.conventions import to_grey
from prismstereo.depth.bad_pixels import BadPixels
from prismstereo.depth.resample import upsample
from prismstereo.depth.result import DepthResult
from prismstereo.epipolar.sweep import fit_sweep, sweep_coefficients, sweep_match, sweep_to_depth
from prismstereo.errors import OptionError, ShapeError, check_option, check_shape
from prismstereo.geometry.optics import check_rig_images, trace_pixels
from prismstereo.geometry.rig import BiPrismRig
from prismstereo.learned.exact_confidence import ConfidenceHead, exact_features, load_head
from prismstereo.learned.exact_stage import EXACT_BAND, ExactStage
from prismstereo.learned.network import normalise_image
from prismstereo.learned.refinement import HybridArchitecture, RefinementCNN, RefinementInputs, classical_config
from prismstereo.learned.sweep_start import StartArchitecture, SweepStart, load_start
from prismstereo.learned.weights import WeightsError, read_weights, state_part, write_weights
from prismstereo.matching.aggregate import box_filter
from prismstereo.matching.band import extend_estimate
from prismstereo.matching.sweep_sampler import block_centres
from prismstereo.names import LAST_STAGES  # what gives the final depth (HybridStereo's ``last_stage``)
from prismstereo.runtime import box_max, sample_bilinear

__all__ = ["HYBRID_BLOCK_WEIGHTS", "HYBRID_FORMAT", "HYBRID_WEIGHTS", "LAST_STAGES", "HybridStereo", "RefinementInputs",
           "classical_config", "load_hybrid_weights"]

HYBRID_WEIGHTS = Path(__file__).resolve().parent / "weights" / "hybrid.pt"
# the stages trained on the classical block level's estimates (``start='classical'``): less dense, faster
HYBRID_BLOCK_WEIGHTS = HYBRID_WEIGHTS.with_name("hybrid_block.pt")
HYBRID_FORMAT = "prismstereo.hybrid/1"
RELIEF_STEPS = 8.0  # the estimate's local relief is given to the CNN in steps, clipped to +- this
# the classical level leaves a margin uncovered at the sensor's edges and along the common field of view's edge (its
# windows leave the other half there); its blocks within this many blocks of a covered one start from their covered
# neighbours' mean s, so the refinement starts near the truth there instead of at s = 0
FILL_RADIUS = 3
VALID_CONFIDENCE = 0.5  # the validity threshold of weights without a calibrated one (``valid_confidence``)


def load_hybrid_weights(path: str | Path) -> tuple[HybridArchitecture, dict[str, torch.Tensor], dict[str, Any]]:
    """Read a weights file written by :meth:`HybridStereo.save`: (architecture, state_dict, metadata).

    Raises:
        WeightsError: missing or unreadable file, or not a HybridStereo weights file.

    Example:
        >>> arch, state, meta = load_hybrid_weights(HYBRID_WEIGHTS)  # doctest: +SKIP
    """
    return read_weights(path, HYBRID_FORMAT, HybridArchitecture, "HybridStereo")


class HybridStereo(nn.Module):
    """Dense depth of the reference half: classical block mode refined by a learned 2-D stage (module docstring).

    Args:
        rig: the full-resolution rig; its sensor size must be divisible by the first stage's cells (4 x 4 of the
            stages' grid), or by the architecture's ``block`` with the classical start.
        z_range: (z_min, z_max) searched, mm; None: the classical model's default
            (:func:`~prismstereo.depth.range.default_z_range`).
        weights: ``'default'`` (the shipped ``weights/hybrid.pt``), None (random initialisation from torch's global
            RNG; the untrained heads keep the classical estimate) or a weights file path.
        architecture: without weights, the hyper-parameters (default :class:`HybridArchitecture` ()).
        last_stage: ``'exact'`` (the classical band's fit on the exact sweep around the learned estimate, where it
            is valid and agrees) or ``'learned'`` (the learned estimate as it is); see the module docstring.

    Attributes:
        binning: b, the stages' grid's binning (2 or 1; module docstring).
        valid_confidence: the confidence from which a depth is valid: the threshold calibrated on the training
            captures for this model's confidence (the head's, ``exact_valid_confidence``, with the exact stage and a
            head; else the learned one's, ``valid_confidence``: in the weights' metadata), else
            :data:`VALID_CONFIDENCE`.
        head: the confidence head (:class:`~prismstereo.learned.exact_confidence.ConfidenceHead`) when the weights
            hold one, else None; used with the exact stage only.
        exact: the exact last stage (:class:`~prismstereo.learned.exact_stage.ExactStage`; None with
            ``last_stage='learned'``).

    Raises:
        OptionError: a sensor the cells or blocks do not divide, or bad options. WeightsError: a weights file that
            cannot be read. RigError: bad rig or range.

    Example:
        >>> model = HybridStereo(thesis_setup1().downscaled(4), (450.0, 1000.0), weights=None)
        >>> out = model(torch.rand(1, 1, 192, 256))
        >>> out.depth.shape, out.valid.dtype
        (torch.Size([1, 1, 192, 128]), torch.bool)
    """

    coefficients: torch.Tensor
    rays_valid: torch.Tensor

    kind = "hybrid"

    def __init__(self, rig: BiPrismRig, z_range: tuple[float, float] | None = None, *,
                 weights: str | Path | None | Literal["default"] = "default",
                 architecture: HybridArchitecture | None = None,
                 last_stage: Literal["exact", "learned"] = "exact") -> None:
        super().__init__()
        from prismstereo.depth.range import check_z_range, default_z_range

        check_option(last_stage, LAST_STAGES, "last_stage")
        if not isinstance(rig, BiPrismRig):
            raise OptionError(f"rig must be a BiPrismRig, got {type(rig).__name__}")
        check_rig_images(rig)
        state, metadata = None, {}
        if weights is not None:
            path = HYBRID_WEIGHTS if isinstance(weights, str) and weights == "default" else Path(weights)
            architecture, state, metadata = load_hybrid_weights(path)
        self.architecture = arch = architecture or HybridArchitecture()
        self.metadata: dict[str, Any] = metadata
        self.binning = b = default_downsample(rig)
        # the classical level's blocks, or the learned first stage's cells: 4 x 4 of the stages' grid
        cell, what = (4 * b, "the first stage's cells") if arch.start == "learned" else (arch.block, "block")
        if rig.image_width % cell or rig.image_height % cell:
            raise OptionError(f"the {rig.image_width}x{rig.image_height} sensor is not divisible by {what} {cell}")
        z = default_z_range(rig) if z_range is None else check_z_range(rig, z_range)
        self.classical = PrismStereo(rig, z, classical_config(arch.block * b // 2))
        self.stages = nn.ModuleList([RefinementCNN(arch) for _ in range(arch.iterations)])
        self.quarter_stages = nn.ModuleList([RefinementCNN(arch) for _ in range(arch.quarter)])
        # the first stage the weights hold (else the shipped), on 4 x 4 cells of the stages' grid on every sensor
        self.start: SweepStart | None = None
        if arch.start == "learned":
            held, start_rig = metadata.get("start_architecture"), rig if b == 2 else rig.unbinned(2)
            self.start = (load_start(start_rig, z) if held is None
                          else SweepStart(start_rig, z, architecture=StartArchitecture.recorded(held)))
        if state is not None:
            try:
                self.stages.load_state_dict(state_part(state, "half"))
                self.quarter_stages.load_state_dict(state_part(state, "quarter"))
            except RuntimeError as exc:
                raise WeightsError(f"weights do not fit the architecture {arch}: {exc}") from exc
            if self.start is not None and (start := state_part(state, "start")):
                self.start.load_weights(start)
        self.head: ConfidenceHead | None = None if state is None else load_head(state)
        self.rig = rig
        self.half = half = rig.binned(b)
        z = self.classical.z_range
        self.last_stage = last_stage
        self.exact = ExactStage(rig, z) if last_stage == "exact" else None
        # the confidence from which a depth is valid: calibrated on the training captures when the weights were
        # written (prismstereo.learned.hybrid_train.validity_threshold, confidence_train.train_exact_confidence)
        key = "exact_valid_confidence" if self.rescored else "valid_confidence"
        self.valid_confidence = float(metadata.get(key, VALID_CONFIDENCE))
        # a step of s: the sweep's largest pixel spacing on the stages' grid is <= 1 px per step
        self.step = 2.0 / (default_hypotheses(half, z) - 1)
        self.register_buffer("coefficients", _sweep_grid(half, z), persistent=False)
        quarter = rig.binned(2 * b)
        self.quarter_size = (quarter.image_height, quarter.reference_width)
        self.quarter_step = 2.0 / (default_hypotheses(quarter, z) - 1)
        self.register_buffer("quarter_coefficients", _sweep_grid(quarter, z) if arch.quarter else torch.zeros(0),
                             persistent=False)
        uv = _pixels(rig)
        rays = trace_pixels(rig, uv)
        self.register_buffer("rays_valid", (rays.valid & rays.left).view(1, 1, *uv.shape[:2]), persistent=False)
        self.bad_pixels = BadPixels(half, z)  # screens the stages' grid: a bin with a bad pixel is bad

    @property
    def rescored(self) -> bool:
        """Whether the confidence is the head's (the exact stage and a head), else the last learned stage's."""
        return self.exact is not None and self.head is not None

    @property
    def z_range(self) -> tuple[float, float]:
        """(z_min, z_max) searched, mm."""
        return self.classical.z_range

    @property
    def num_hypotheses(self) -> int:
        """D of the classical level (``index`` is a fractional index into its ``depths``)."""
        return self.classical.num_hypotheses

    @property
    def depths(self) -> torch.Tensor:
        """(D,) the classical level's hypotheses, mm."""
        return self.classical.depths

    def tracker(self, options: TemporalOptions | None = None) -> TemporalDepth | None:
        """The temporal band that tracks this model's depth between key frames of a video: the classical default
        model's of the same rig and range (:meth:`~prismstereo.classical.model.PrismStereo.tracker`; the hybrid has
        no band of its own), None where that model has none.

        Example:
            >>> model = HybridStereo(thesis_setup1().downscaled(2), (450.0, 1000.0), weights=None)
            >>> model.tracker().rig == model.rig
            True
        """
        return PrismStereo(self.rig, self.z_range).tracker(options)

    def weights(self) -> dict[str, torch.Tensor]:
        """The learned tensors (what a weights file holds): ``half.*`` and ``quarter.*`` stages, ``start.*`` the
        learned first stage's (``architecture.start == 'learned'``) and ``head.*`` the confidence head's."""
        start = {} if self.start is None else {f"start.{k}": v for k, v in self.start.weights().items()}
        head = {} if self.head is None else {f"head.{k}": v for k, v in self.head.state_dict().items()}
        return {**{f"half.{k}": v for k, v in self.stages.state_dict().items()},
                **{f"quarter.{k}": v for k, v in self.quarter_stages.state_dict().items()}, **start, **head}

    def describe(self) -> dict[str, Any]:
        """What the model is, JSON-ready (the ONNX export's metadata and cache key).

        Example:
            >>> HybridStereo(thesis_setup1().downscaled(4), (450.0, 1000.0), weights=None).describe()["model"]
            'HybridStereo'
        """
        digest = hashlib.sha256()
        for name, tensor in sorted(self.weights().items()):
            digest.update(name.encode())
            digest.update(tensor.detach().float().cpu().numpy().tobytes())
        return {"model": "HybridStereo", "z_range_mm": list(self.z_range), "num_hypotheses": self.num_hypotheses,
                "architecture": dataclasses.asdict(self.architecture), "classical": self.classical.describe(),
                "weights_sha256": digest.hexdigest()[:16], "valid_confidence": self.valid_confidence,
                "last_stage": self.last_stage}

    def summary(self) -> str:
        """The model in one line.

        Example:
            >>> summary = HybridStereo(thesis_setup1().downscaled(4), (450.0, 1000.0), weights=None).summary()
            >>> summary.startswith("hybrid: learned first stage ("), "at 1/4)" in summary  # a small sensor
            (True, True)
        """
        a = self.architecture
        count = sum(v.numel() for v in self.weights().values())
        grids = {1: "full resolution", 2: "1/2", 4: "1/4"}
        stages = " and ".join(f"{n} at {grids[k * self.binning]}" for n, k in ((a.quarter, 2), (a.iterations, 1))
                              if n)
        first = (f"learned first stage ({self.start.num_hypotheses} hypotheses at 1/{4 * self.binning})"
                 if self.start is not None
                 else f"classical block level ({self.classical.summary()})")
        last = "" if self.exact is None else f", then the exact band +-{EXACT_BAND} at {grids[self.exact.binning]}"
        last += ", its evidence re-scoring the confidence" if self.rescored else ""
        return (f"hybrid: {first}, then learned 2-D stages: "
                f"{stages} ({a.layers} x {a.channels} ch, {count} parameters){last}")

    def save(self, path: str | Path, **metadata: Any) -> Path:
        """Write the CNNs' weights with the architecture and ``metadata`` (small, plain values); a learned first
        stage's architecture goes into the metadata (``start_architecture``), so the file holds all of it."""
        if self.start is not None:
            metadata = {"start_architecture": dataclasses.asdict(self.start.architecture), **metadata}
        return write_weights(path, HYBRID_FORMAT, self.architecture, self.weights(), {**self.metadata, **metadata})

    def initial(self, image: torch.Tensor) -> RefinementInputs:
        """Steps 1-2: the classical estimate and the normalised capture on the stages' grid.

        Args:
            image: (B, C, H, W) captures in [0, 1] of the rig's sensor.

        Returns:
            RefinementInputs, (B, *, h, w) maps.
        """
        self._check(image)
        return self.initial_binned(_binned(to_grey(image.to(self.coefficients.dtype)), self.binning))

    def initial_binned(self, grey: torch.Tensor) -> RefinementInputs:
        """:meth:`initial` of the grey capture ``grey`` (B, 1, H/b, W/b) on the stages' grid (b = :attr:`binning`;
        training keeps captures so).

        Example:
            >>> model = HybridStereo(thesis_setup1().downscaled(2), (450.0, 1000.0), weights=None)
            >>> model.binning, model.initial_binned(torch.rand(1, 1, 384, 512)).s.shape  # the classical grid
            (1, torch.Size([1, 1, 192, 128]))
        """
        k = self.architecture.block
        image = normalise_image(grey)
        with torch.no_grad():
            if self.start is not None:  # the learned first stage on 4 x 4 cells, carried to the classical grid
                out = self.start(image)
                s, confidence, covered = upsample(torch.cat([out.s, out.confidence, out.covered], 1), 2,
                                                  self.quarter_size, mode="bilinear").split(1, 1)
                return RefinementInputs(image, s, confidence, (covered > 0.5).to(grey.dtype))
            block = self.classical.block_estimate(grey if k == 2 else F.avg_pool2d(grey, k // 2))
            s = extend_estimate(block.s, block.covered, FILL_RADIUS).s
        return RefinementInputs(image, s, block.confidence, block.covered.to(grey.dtype))

    def _check(self, image: torch.Tensor) -> None:
        check_shape(image, ["B", "C", "H", "W"], "image")
        rig = self.rig
        if not torch.is_floating_point(image) or image.shape[1] not in (1, 3) or tuple(image.shape[-2:]) != (
                rig.image_height, rig.image_width):
            raise ShapeError(f"image must be a floating-point (B, 1 or 3, {rig.image_height}, {rig.image_width}) "
                             f"tensor in [0, 1], got {image.dtype} {tuple(image.shape)}")

    def sample_costs(self, image: torch.Tensor, s: torch.Tensor, window: tuple[int, int] = (0, 0),
                     quarter: bool = False) -> torch.Tensor:
        """Step 3: the cost curve around ``s``: (B, 2 offsets + 1, h, w) mean absolute differences (3 x 3) of the
        locally normalised reference and the other half sampled along the exact sweep at s + o steps (the match
        at s exact to the sweep fit, the offsets to first order in o: their cost only guides the CNN).

        Args:
            image: (B, 2, h, W2) the normalised binned capture at the stage's resolution.
            s: (B, 1, h', w') sweep coordinates of the reference pixels from row, column ``window`` on (training
                refines crops).
            quarter: on the quarter stages' grid (else the stages' grid).
        """
        n = self.architecture.offsets
        b, _, h, w = s.shape
        coefficients, step = (self.quarter_coefficients, self.quarter_step) if quarter else (self.coefficients,
                                                                                            self.step)
        match, slope = sweep_match(_crop(coefficients, window, (h, w)), s)  # (B, 2, h, w) each
        offsets = torch.arange(-n, n + 1, dtype=s.dtype, device=s.device).view(1, -1, 1, 1, 1) * step
        at = match.unsqueeze(1) + offsets * slope.unsqueeze(1)  # (B, O, 2, h, w)
        local = image[:, 1:2]
        warped = sample_bilinear(local, at[:, :, 0], at[:, :, 1])[:, 0]  # (B, O, h, w)
        return box_filter((_crop(local, window, (h, w)) - warped).abs(), 3)

    def _stage(self, stage: RefinementCNN, image: torch.Tensor, s: torch.Tensor, confidence: torch.Tensor,
               covered: torch.Tensor, window: tuple[int, int], quarter: bool) -> tuple[torch.Tensor, torch.Tensor]:
        h, w = s.shape[-2:]
        step = self.quarter_step if quarter else self.step
        relief = ((s - box_filter(s, 5)) / step).clamp(-RELIEF_STEPS, RELIEF_STEPS) / RELIEF_STEPS
        x = torch.cat([_crop(image, window, (h, w)), self.sample_costs(image, s, window, quarter), relief,
                       confidence, covered], 1)
        delta, logit = stage(x).split(1, 1)
        return (s + delta * step).clamp(-1.0, 1.0), logit

    def refine(self, inputs: RefinementInputs, window: tuple[int, int] = (0, 0),
               size: tuple[int, int] | None = None) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """Step 2: the quarter stages on the classical grid, the maps bilinearly onto the stages' grid (block centres
        kept), its stages. Returns every stage's s and confidence logit on the stages' grid, (B, 1, h, w) each.

        Args:
            inputs: the classical estimate, or a crop of it from row, column ``window`` of its grid on (its
                ``image`` the whole capture; training refines crops).
            window: the crop's origin on the classical grid.
            size: (h, w) on the stages' grid; None: the whole reference half.
        """
        s, confidence, covered = inputs.s, inputs.confidence, inputs.covered
        f = self.architecture.block // 2
        if size is None:
            size = (self.half.image_height, self.half.reference_width)
        out, logit = [], None
        if len(self.quarter_stages):
            image = F.avg_pool2d(inputs.image, 2)
            for stage in self.quarter_stages:
                s, logit = self._stage(stage, image, s, confidence, covered, window, True)
                out.append(tuple(upsample(torch.cat([s, logit], 1), f, size, mode="bilinear").split(1, 1)))
        # a block level may end short of the grid: its last row and column repeated
        s, confidence, covered = upsample(torch.cat([s, confidence, covered], 1), f, size, mode="bilinear").split(1, 1)
        window = (window[0] * f, window[1] * f)
        for stage in self.stages:
            s, logit = self._stage(stage, inputs.image, s, confidence, covered, window, False)
            out.append((s, logit))
        return out

    def forward(self, image: torch.Tensor) -> DepthResult:
        """Depth of the reference half of captures ``image`` (B, C, H, W) in [0, 1] (colour: its
        :func:`~prismstereo.conventions.to_grey`).

        Returns:
            :class:`~prismstereo.depth.result.DepthResult`: depth (B, 1, H, W_ref) mm on every ray that sees
            through the prism; valid (B, 1, H, W_ref) bool (confidence >= :attr:`valid_confidence`, the weights'
            calibrated threshold); confidence (B, 1, H, W_ref) in
            [0, 1] (trained as the probability of a depth within 1 % of the truth; 0 exactly where there is no
            depth); index into :attr:`depths`; match (B, 2, H, W_ref), the match of the last stage's grid
            (interpolated from the stages' grid where it is binned).

        Raises:
            ShapeError: an image that is not (B, 1 or 3, H, W) of the rig's sensor, or not floating point.
        """
        dtype, b = self.coefficients.dtype, self.binning
        self._check(image)
        # screened on the stages' grid: a bin holding a non-finite pixel is non-finite itself
        grey, touched = self.bad_pixels(_binned(to_grey(image.to(dtype)), b))
        s, logit = self.refine(self.initial_binned(grey))[-1]
        if b > 1:  # a bin next to a touched one too: the bilinear upsample below then gives 0 on every touched pixel
            touched = box_max(touched.to(dtype), 3) > 0
        if self.exact is not None:
            evidence = self.exact.evidence(grey, s)
            s = evidence.s
            if self.head is not None:
                logit = self.head(exact_features(evidence, logit, self.step))
        confidence = torch.sigmoid(logit) * (~touched).to(dtype)  # no depth where bad pixels reach (so invalid)
        match = sweep_match(self.coefficients, s)[0] * b + (b - 1) / 2  # full-sensor pixels
        if b > 1:  # each map on its own: the exported graph keeps only what its outputs need (not the match)
            size = (self.rig.image_height, self.rig.reference_width)
            s, confidence, match = (upsample(t, b, size, mode="bilinear") for t in (s, confidence, match))
        confidence = confidence * self.rays_valid.to(dtype)
        z_range = torch.tensor(self.z_range, dtype=s.dtype, device=s.device)
        depth = sweep_to_depth(s, z_range)
        out = image.dtype
        return DepthResult(depth.to(out), confidence >= self.valid_confidence, confidence.to(out),
                           ((s + 1.0) / self.classical.step).to(out), match.to(out))


def _pixels(rig: BiPrismRig) -> torch.Tensor:
    """(H, W_ref, 2) float64 (u, v) of the pixels of the rig's reference half."""
    return block_centres(rig.image_height, rig.reference_width, 1, torch.zeros((), dtype=torch.float64))


def _sweep_grid(rig: BiPrismRig, z_range: tuple[float, float]) -> torch.Tensor:
    """(K, 2, H, W_ref) sweep coefficients of every reference pixel of ``rig`` (:func:`sweep_match`'s)."""
    return sweep_coefficients(fit_sweep(rig, z_range), _pixels(rig)).permute(2, 3, 0, 1).to(torch.get_default_dtype())


def _binned(grey: torch.Tensor, b: int) -> torch.Tensor:
    """``grey`` box-averaged over b x b blocks (itself for b = 1: an exported pooling of 1 is a copy)."""
    return grey if b == 1 else F.avg_pool2d(grey, b)


def _crop(t: torch.Tensor, window: tuple[int, int], size: tuple[int, int]) -> torch.Tensor:
    """The ``size`` crop of ``t`` (..., H, W) from ``window`` on; ``t`` itself when that is all of it (an exported Slice
    copies even a whole tensor)."""
    (r, c), (h, w) = window, size
    return t if (r, c) == (0, 0) and tuple(t.shape[-2:]) == (h, w) else t[..., r:r + h, c:c + w]
