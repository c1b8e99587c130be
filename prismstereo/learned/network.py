"""LearnedStereo: a small CNN around the exact bi-prism plane sweep (:mod:`prismstereo.nn`).

Data path (one capture, both halves side by side as recorded; B batch, D hypotheses, G groups, s = ``scale``):

1. grey (:func:`~prismstereo.conventions.to_grey`), normalised per image (zero mean, unit standard deviation) and
   locally (9 x 9 window): two channels, so that brightness and contrast matter less;
2. a feature CNN on the whole capture down to 1/s (stride-2 convolutions of kernel 4 and padding 1, so feature
   pixel i is centred on the block centre s i + (s - 1) / 2, the ray of the binned rig's pixel i);
3. :class:`~prismstereo.nn.PrismCostVolume` with G groups on the exact sweep of the given rig: (B, G, D, h, w_ref);
4. a few 3-D convolutions over (D, h, w_ref) to one score per hypothesis, then
   :func:`~prismstereo.nn.depth_regression` (soft-argmax in 1/Z);
5. the fractional hypothesis index upsampled bilinearly to full resolution, plus a residual and a confidence
   logit from a small 2-D CNN guided by the reference image.

The learned weights are the CNNs only: the sweep grid, the hypotheses and the validity masks are buffers built
from whatever rig and range the model is constructed with, and the 3-D convolutions do not depend on D, so the
same weights run on any rig at any resolution whose size the feature stride divides.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import Any, Literal, NamedTuple

import torch
import torch.nn.functional as F
from torch import nn

from prismstereo.conventions import to_grey
from prismstereo.depth.bad_pixels import BAD_PIXEL_REACH, BadPixels, discard
from prismstereo.depth.result import DepthResult
from prismstereo.epipolar.sweep import depth_to_sweep, evaluate_sweep, fit_sweep, sweep_coefficients, sweep_to_depth
from prismstereo.errors import OptionError, ShapeError, check_shape
from prismstereo.geometry.optics import check_rig_images, trace_pixels
from prismstereo.geometry.rig import BiPrismRig
from prismstereo.learned.weights import WeightsError, read_weights, write_weights
from prismstereo.matching.aggregate import box_filter
from prismstereo.nn import PrismCostVolume, depth_regression
from prismstereo.runtime import exporting

__all__ = ["LEARNED_WEIGHTS", "FORMAT", "HYPOTHESIS_SPACING_PX", "Architecture", "LearnedStereo",
           "learned_hypotheses", "load_weights"]

LEARNED_WEIGHTS = Path(__file__).resolve().parent / "weights" / "thesis_setup1.pt"
"""The shipped weights of :class:`LearnedStereo` (the hybrid's: :data:`~prismstereo.learned.hybrid.HYBRID_WEIGHTS`)."""
# the spacing of neighbouring hypotheses on the sweep at the feature stride (px) that the default count keeps on every
# rig and range: the shipped weights' (trained with 24 hypotheses over 450-1000 mm on setup 1 binned by 2, 16 px of
# sweep at stride 4 in 23 steps, 0.70 px; run with 48 at full resolution, 32 px in 47 steps, 0.68 px)
HYPOTHESIS_SPACING_PX = 0.69
FORMAT = "prismstereo.learned/1"
SCALES = (2, 4, 8)


@dataclasses.dataclass(frozen=True)
class Architecture:
    """The hyper-parameters that shape the weights (stored beside them in a weights file).

    Attributes:
        scale: feature stride, 2, 4 or 8 (the cost volume's binning).
        feature_channels: C, channels of the feature map correlated by the volume.
        groups: G correlation groups (C must be a multiple of G).
        aggregation_channels: channels of the 3-D convolutions.
        refine_channels: channels of the full-resolution refinement.

    Example:
        >>> Architecture().scale, Architecture(scale=8).groups
        (4, 8)
    """

    scale: int = 4
    feature_channels: int = 32
    groups: int = 8
    aggregation_channels: int = 16
    refine_channels: int = 16

    def __post_init__(self) -> None:
        if self.scale not in SCALES:
            raise OptionError(f"Unknown scale {self.scale!r}. Choose from: {', '.join(map(str, SCALES))}")
        for name in ("feature_channels", "groups", "aggregation_channels", "refine_channels"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < 1:
                raise OptionError(f"{name} must be an int >= 1, got {value!r}")
        if self.feature_channels % self.groups:
            raise OptionError(f"feature_channels ({self.feature_channels}) must be a multiple of groups "
                              f"({self.groups})")


class _Parts(NamedTuple):
    """Internal outputs (training needs the coarse estimate and the confidence logit)."""

    coarse: torch.Tensor  # (B, 1, H, W_ref) fractional index of the regression, upsampled
    index: torch.Tensor  # (B, 1, H, W_ref) refined fractional index, clamped to [0, D - 1]
    logit: torch.Tensor  # (B, 1, H, W_ref) confidence logit
    inside: torch.Tensor  # (1, 1, H, W_ref) bool, valid reference rays with at least one valid hypothesis


def _conv(cin: int, cout: int, k: int = 3, stride: int = 1, dilation: int = 1) -> nn.Conv2d:
    return nn.Conv2d(cin, cout, k, stride, padding=dilation * (k - 1) // 2 if stride == 1 else 1, dilation=dilation)


def _features(arch: Architecture) -> nn.Sequential:
    c = arch.feature_channels
    widths = [24] + [c] * (int(math.log2(arch.scale)) - 1)
    layers: list[nn.Module] = []
    cin = 2
    for width in widths:  # kernel 4, stride 2, padding 1: output pixel j centred on input 2 j + 1/2
        layers += [_conv(cin, width, 4, 2), nn.ReLU(), _conv(width, width), nn.ReLU()]
        cin = width
    layers += [_conv(cin, c, dilation=2), nn.ReLU(), nn.Conv2d(c, c, 1)]
    return nn.Sequential(*layers)


def _aggregation(arch: Architecture) -> nn.Sequential:
    a = arch.aggregation_channels
    return nn.Sequential(
        nn.Conv3d(arch.groups, a, 3, padding=1), nn.ReLU(),
        nn.Conv3d(a, a, 3, padding=1), nn.ReLU(),
        nn.Conv3d(a, a, 3, padding=(1, 2, 2), dilation=(1, 2, 2)), nn.ReLU(),
        nn.Conv3d(a, 1, 3, padding=1),
    )


def _refinement(arch: Architecture) -> nn.Sequential:
    r = arch.refine_channels
    head = nn.Conv2d(r, 2, 3, padding=1)
    nn.init.zeros_(head.weight)
    nn.init.zeros_(head.bias)
    return nn.Sequential(_conv(4, r), nn.ReLU(), _conv(r, r, dilation=2), nn.ReLU(), head)


def normalise_image(image: torch.Tensor, window: int = 9) -> torch.Tensor:
    """Grey, normalised globally and locally: (B, C, H, W) in [0, 1] -> (B, 2, H, W).

    Channel 0: (g - mean) / (std + 0.01) over each image; channel 1: (g - local mean) / (local std + 0.01) in a
    ``window`` x ``window`` box (edge pixels use the part inside the image).

    Example:
        >>> normalise_image(torch.rand(2, 3, 16, 20)).shape
        torch.Size([2, 2, 16, 20])
    """
    grey = to_grey(image)
    mean = grey.mean((2, 3), keepdim=True)
    std = (grey - mean).square().mean((2, 3), keepdim=True).sqrt()
    local, local_sq = box_filter(torch.cat([grey, grey.square()], 1), window).split(1, 1)
    local_std = (local_sq - local.square()).clamp_min(1e-12).sqrt()  # floored: a flat window's gradient stays finite
    return torch.cat([(grey - mean) / (std + 0.01), (grey - local) / (local_std + 0.01)], 1)


def load_weights(path: str | Path) -> tuple[Architecture, dict[str, torch.Tensor], dict[str, Any]]:
    """Read a weights file written by :meth:`LearnedStereo.save`.

    Returns:
        (architecture, state_dict, metadata).

    Raises:
        WeightsError: missing or unreadable file, or not a LearnedStereo weights file.

    Example:
        >>> arch, state, meta = load_weights(LEARNED_WEIGHTS)
        >>> arch.scale, meta["rig"]
        (4, 'thesis_setup1')
    """
    return read_weights(path, FORMAT, Architecture, "LearnedStereo")


def learned_hypotheses(rig: BiPrismRig, z_range_mm: tuple[float, float], scale: int = 4,
                       spacing_px: float = HYPOTHESIS_SPACING_PX) -> int:
    """The learned model's default D: hypotheses uniform in the sweep parameter whose neighbours are at most
    ``spacing_px`` apart on every reference pixel's sweep at the feature stride ``scale`` (the rig binned by it), so
    that a wider range gets more hypotheses at the spacing the weights were trained with (the classical model's rule,
    :func:`~prismstereo.classical.defaults.default_hypotheses`, at the cost volume's resolution).

    Args:
        rig: the full-resolution rig.
        z_range_mm: (z_min, z_max).
        scale: the feature stride.
        spacing_px: the largest neighbour spacing (px at the stride).

    Returns:
        D >= 2.

    Example:
        >>> learned_hypotheses(thesis_setup1(), (450.0, 1000.0)), learned_hypotheses(thesis_setup1(), (200.0, 1600.0))
        (48, 168)
    """
    from prismstereo.classical.defaults import default_hypotheses

    if not (isinstance(spacing_px, (int, float)) and spacing_px > 0):
        raise OptionError(f"spacing_px must be a positive number, got {spacing_px!r}")
    intervals = default_hypotheses(rig.binned(scale), z_range_mm) - 1  # steps of <= 1 px: the sweep's length
    return max(2, math.ceil(intervals / spacing_px) + 1)


class LearnedStereo(nn.Module):
    """Learned depth of the reference half on the exact prism sweep (see the module docstring).

    Args:
        rig: the full-resolution rig; its sensor size must be divisible by ``scale``. Its geometry is checked
            first (:func:`~prismstereo.geometry.optics.check_rig_images`), here and in :meth:`for_rig`.
        z_range: (z_min, z_max) searched, mm, beyond the prism's back plane.
        num_hypotheses: D >= 2, uniform in 1/Z; None: :func:`learned_hypotheses` of the rig and range.
        scale: feature stride (2, 4 or 8); part of the architecture.
        weights: ``'default'`` (the shipped ``weights/thesis_setup1.pt``), None (random initialisation from torch's
            global RNG) or a weights file path.
        architecture: the other hyper-parameters; default those of the weights file, or :class:`Architecture`
            (scale) without one.
        with_match: fill ``match`` from the sweep fit (a (H, W_ref, 13, 2) buffer of per-pixel polynomials);
            False leaves it NaN.

    Raises:
        OptionError: bad scale, sizes or architecture. WeightsError: a weights file that cannot be read or whose
            architecture differs from the model's. RigError: bad rig or range.

    Example:
        >>> model = LearnedStereo(thesis_setup1().downscaled(8), (450.0, 1000.0), num_hypotheses=16)
        >>> out = model(torch.rand(1, 1, 96, 128))
        >>> out.depth.shape, out.valid.dtype, out.match.shape
        (torch.Size([1, 1, 96, 64]), torch.bool, torch.Size([1, 2, 96, 64]))
    """

    coefficients: torch.Tensor
    rays_valid: torch.Tensor
    kind = "learned"

    def __init__(
        self,
        rig: BiPrismRig,
        z_range: tuple[float, float],
        *,
        num_hypotheses: int | None = None,
        scale: int = 4,
        weights: str | Path | None | Literal["default"] = "default",
        architecture: Architecture | None = None,
        with_match: bool = True,
    ) -> None:
        super().__init__()
        if not isinstance(rig, BiPrismRig):
            raise OptionError(f"rig must be a BiPrismRig, got {type(rig).__name__}")
        check_rig_images(rig)
        state = metadata = None
        if weights is not None:
            path = LEARNED_WEIGHTS if isinstance(weights, str) and weights == "default" else Path(weights)
            file_arch, state, metadata = load_weights(path)
            architecture = architecture or file_arch
            if dataclasses.replace(architecture, scale=scale) != file_arch:
                raise WeightsError(f"{path} was trained for {file_arch}, the model is "
                                   f"{dataclasses.replace(architecture, scale=scale)}")
        self.architecture = dataclasses.replace(architecture or Architecture(), scale=scale)
        self.metadata: dict[str, Any] = metadata or {}
        self.features = _features(self.architecture)
        # channels-last 3-D convolutions take oneDNN's fast CPU path (benchmarks/learned.py times the model); values
        # are unchanged
        self.aggregation = _aggregation(self.architecture).to(memory_format=torch.channels_last_3d)
        self.refinement = _refinement(self.architecture)
        if state is not None:
            try:
                self.load_state_dict(state)
            except RuntimeError as exc:
                raise WeightsError(f"weights do not fit the architecture {self.architecture}: {exc}") from exc
        self._attach(rig, z_range, num_hypotheses, with_match)

    def _attach(self, rig: BiPrismRig, z_range: tuple[float, float], num_hypotheses: int | None,
                with_match: bool) -> None:
        """Build the rig-dependent buffers (not part of the state dict)."""
        s = self.architecture.scale
        if rig.image_width % s or rig.image_height % s:
            raise OptionError(f"the {rig.image_width}x{rig.image_height} sensor is not divisible by scale {s}")
        if num_hypotheses is None:
            from prismstereo.depth import check_z_range

            num_hypotheses = learned_hypotheses(rig, check_z_range(rig, z_range), s)
        self.rig, self.with_match = rig, bool(with_match)
        self.volume = PrismCostVolume(rig, z_range, num_hypotheses, s, groups=self.architecture.groups)
        self.z_range = self.volume.z_range_mm
        self.num_hypotheses = num_hypotheses
        h, w_ref = rig.image_height, rig.reference_width
        v, u = torch.meshgrid(torch.arange(h, dtype=torch.float64), torch.arange(w_ref, dtype=torch.float64),
                              indexing="ij")
        uv = torch.stack([u, v], -1)
        rays = trace_pixels(rig, uv)
        self.register_buffer("rays_valid", (rays.valid & rays.left).view(1, 1, h, w_ref), persistent=False)
        self.bad_pixels = BadPixels(rig, self.z_range, radius=BAD_PIXEL_REACH * s)
        if self.with_match:
            coefficients = sweep_coefficients(fit_sweep(rig, self.z_range), uv)
        else:
            coefficients = torch.zeros(0)
        self.register_buffer("coefficients", coefficients.to(torch.get_default_dtype()), persistent=False)

    def for_rig(self, rig: BiPrismRig, z_range: tuple[float, float], *, num_hypotheses: int | None = None,
                with_match: bool | None = None) -> LearnedStereo:
        """A model for another rig or range that shares this one's CNNs (same parameter tensors); ``num_hypotheses``
        None: :func:`learned_hypotheses` of that rig and range.

        Example:
            >>> model = LearnedStereo(thesis_setup1().downscaled(8), (450.0, 1000.0), weights=None)
            >>> other = model.for_rig(thesis_setup1().downscaled(4), (300.0, 1500.0), num_hypotheses=8)
            >>> other.features is model.features, other.volume.depths.shape
            (True, torch.Size([8]))
        """
        with torch.random.fork_rng(devices=[]):  # its own CNNs are replaced: their initialisation draws nothing
            twin = LearnedStereo(rig, z_range, num_hypotheses=num_hypotheses,
                                 scale=self.architecture.scale, weights=None, architecture=self.architecture,
                                 with_match=self.with_match if with_match is None else with_match)
        twin.metadata = self.metadata
        twin.features, twin.aggregation, twin.refinement = self.features, self.aggregation, self.refinement
        return twin.to(next(self.parameters()))

    def tracker(self, options: Any = None) -> None:
        """None: the learned model has no band to place on a previous frame (a video's frames are computed each on
        its own).

        Example:
            >>> LearnedStereo(thesis_setup1().downscaled(8), (450.0, 1000.0), num_hypotheses=8).tracker() is None
            True
        """
        return None

    def describe(self) -> dict[str, Any]:
        """What the model is, JSON-ready (the ONNX export's metadata and cache key): its class, range, hypotheses,
        architecture and a digest of the weights.

        Example:
            >>> described = LearnedStereo(thesis_setup1().downscaled(8), (450.0, 1000.0), num_hypotheses=16).describe()
            >>> described["model"], described["num_hypotheses"], len(described["weights_sha256"])
            ('LearnedStereo', 16, 16)
        """
        import hashlib

        digest = hashlib.sha256()
        for name, tensor in sorted(self.state_dict().items()):
            if not name.startswith("volume."):
                digest.update(name.encode())
                digest.update(tensor.detach().float().cpu().numpy().tobytes())
        return {"model": "LearnedStereo", "z_range_mm": list(self.z_range), "num_hypotheses": self.num_hypotheses,
                "architecture": dataclasses.asdict(self.architecture), "with_match": self.with_match,
                "weights_sha256": digest.hexdigest()[:16]}

    def summary(self) -> str:
        """The model in one line (for logs and the CLI).

        Example:
            >>> LearnedStereo(thesis_setup1().downscaled(8), (450.0, 1000.0), num_hypotheses=16).summary()
            'learned model: 58835 parameters, 16 hypotheses on 1/4-resolution features'
        """
        count = sum(p.numel() for p in self.parameters())
        return (f"learned model: {count} parameters, {self.num_hypotheses} hypotheses on "
                f"1/{self.architecture.scale}-resolution features")

    def index_to_depth(self, index: torch.Tensor) -> torch.Tensor:
        """Depth (mm) of fractional hypothesis indices (any shape): the hypotheses are uniform in 1/Z.

        Example:
            >>> model = LearnedStereo(thesis_setup1().downscaled(8), (450.0, 900.0), num_hypotheses=3, weights=None)
            >>> model.index_to_depth(torch.tensor([0.0, 1.0, 2.0]))
            tensor([450., 600., 900.])
        """
        return sweep_to_depth(index * (2.0 / (self.num_hypotheses - 1)) - 1.0, self.z_range)

    def depth_to_index(self, depth: torch.Tensor) -> torch.Tensor:
        """Fractional hypothesis index of depths (mm, any shape), the inverse of :meth:`index_to_depth`."""
        return (depth_to_sweep(depth, self.z_range) + 1.0) * ((self.num_hypotheses - 1) / 2.0)

    def extra_repr(self) -> str:
        return (f"z_range={self.z_range}, num_hypotheses={self.num_hypotheses}, "
                f"sensor={self.rig.image_width}x{self.rig.image_height}, {self.architecture}")

    def save(self, path: str | Path, **metadata: Any) -> Path:
        """Write the CNN weights (state dict) with the architecture and ``metadata`` (small, plain values).

        Example:
            >>> import tempfile
            >>> model = LearnedStereo(thesis_setup1().downscaled(8), (450.0, 1000.0), weights=None)
            >>> with tempfile.TemporaryDirectory() as tmp:
            ...     path = model.save(Path(tmp) / "w.pt", note="example")
            ...     load_weights(path)[2]["note"]
            'example'
        """
        state = {k: v for k, v in self.state_dict().items()
                 if not k.startswith("volume.")}  # the CNNs only: the volume's grid comes from the rig
        return write_weights(path, FORMAT, self.architecture, state, {**self.metadata, **metadata})

    def _check(self, image: torch.Tensor) -> None:
        check_shape(image, ["B", "C", "H", "W"], "image")
        if not torch.is_floating_point(image):
            raise ShapeError(f"image must be a floating-point tensor in [0, 1], got {image.dtype}")
        rig = self.rig
        if image.shape[1] not in (1, 3) or tuple(image.shape[-2:]) != (rig.image_height, rig.image_width):
            raise ShapeError(f"image must be (B, 1 or 3, {rig.image_height}, {rig.image_width}), got "
                             f"{tuple(image.shape)}")

    def _parts(self, image: torch.Tensor) -> _Parts:
        """Everything up to the final index (training uses this directly)."""
        self._check(image)
        dtype = self.volume.depths.dtype
        x = normalise_image(image.to(dtype))
        volume = self.volume(self.features(x))
        if not exporting():  # the layout is a CPU speed-up the exporter does not take
            volume = volume.contiguous(memory_format=torch.channels_last_3d)
        cost = self.aggregation(volume)[:, 0]  # (B, D, h, w_b)
        regression = depth_regression(cost, self.volume.depths, self.volume.valid)
        d = self.num_hypotheses
        low = self.depth_to_index(regression.depth)
        w_ref = self.rig.reference_width
        s = self.architecture.scale
        inside_low = self.volume.valid.any(0).view(1, 1, *self.volume.valid.shape[1:]).to(dtype)
        up = F.interpolate(torch.cat([low, regression.confidence, inside_low.expand_as(low)], 1), scale_factor=s,
                           mode="bilinear", align_corners=False)
        if up.shape[-1] < w_ref:  # the reference half reaches into the last block column
            up = F.pad(up, (0, w_ref - up.shape[-1]), mode="replicate")
        up = up[..., :w_ref]
        coarse = up[:, :1]
        guide = torch.cat([x[..., :w_ref], coarse * (2.0 / (d - 1)) - 1.0, up[:, 1:2]], 1)
        delta, logit = self.refinement(guide).split(1, 1)
        index = (coarse + delta).clamp(0.0, d - 1.0)
        inside = self.rays_valid & (up[:1, 2:3] > 0.5)
        return _Parts(coarse, index, logit, inside)

    def forward(self, image: torch.Tensor) -> DepthResult:
        """Depth of the reference half of captures ``image`` (B, C, H, W) in [0, 1] (colour: its
        :func:`~prismstereo.conventions.to_grey`).

        Returns:
            :class:`~prismstereo.depth.result.DepthResult`: depth (B, 1, H, W_ref) mm; valid (B, 1, H, W_ref) bool
            (confidence >= 0.5 on valid reference rays that have a valid hypothesis); confidence (B, 1, H, W_ref)
            in [0, 1] (trained as the probability of a depth within 1 % of the truth; 0 outside); index
            (B, 1, H, W_ref) fractional hypothesis index; match (B, 2, H, W_ref) right-half (u, v) at the
            estimated sweep coordinate (NaN without ``with_match``). Floating outputs in the input's dtype.

        Raises:
            ShapeError: an image that is not (B, 1 or 3, H, W) of the rig's sensor, or not floating point.
        """
        self._check(image)
        image, touched = self.bad_pixels(image)
        parts = self._parts(image)
        depth = self.index_to_depth(parts.index)
        confidence = torch.sigmoid(parts.logit) * parts.inside.to(parts.logit.dtype)
        valid = confidence >= 0.5
        if self.with_match:
            sweep = parts.index[:, 0] * (2.0 / (self.num_hypotheses - 1)) - 1.0  # (B, H, W_ref)
            match = evaluate_sweep(self.coefficients.unsqueeze(0), sweep).permute(0, 3, 1, 2)
        else:
            match = torch.full_like(depth, math.nan).expand(-1, 2, -1, -1)
        out = image.dtype
        return discard(DepthResult(depth.to(out), valid, confidence.to(out), parts.index.to(out), match.to(out)),
                       touched)
