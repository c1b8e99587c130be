"""The learned first stage: learned features correlated along the exact sweep over the whole range at 1/8, aggregated
by 2-D convolutions, so that a match is found where fixed windows fail (weak texture, brightness changes, repeated
patterns).

Data path (one capture; h, w the reference half binned 8 x 8, D hypotheses):

1. a small CNN on the normalised 2 x 2-binned capture (:func:`~prismstereo.learned.network.normalise_image`, both
   halves side by side) down to 1/8 of the sensor: two convolutions of kernel 4, stride 2 and padding 1 (feature
   pixel j centred on sensor pixel 8 j + 7/2, the ray of the 8 x 8-binned rig's pixel j), C channels;
2. a G-group correlation of the two halves over the whole range (thesis eq. 3.1-3.10 traced; the virtual epipolar
   curve of eq. 4.1-4.10 exactly), D hypotheses from the range and rig, neighbours <= 1 px apart at 1/8:
   ``'rectified'`` (the default): whole-pixel column shifts on row-rectified features
   (:class:`~prismstereo.nn.rectified_volume.RectifiedCostVolume`: (B, G, D, w, h), transposed, a fractional shift
   turned into the sweep coordinate s exactly), or ``'sweep'``: D hypotheses uniform in s (linear in 1/Z), each
   sampled bilinearly on its exact sweep (:class:`~prismstereo.nn.PrismCostVolume`; onnxruntime samples it on one
   thread, several times slower);
3. aggregation by 2-D convolutions shared by every hypothesis (a 3 x 3 one with the reference features' context
   added, a dilated 3 x 3 one and a 3 x 3 head), so the weights do not depend on D: any range, any rig. By default
   (:class:`StartArchitecture`) they work on the correlation pooled 2 x 2, with two coarser levels (pooled 4 x 4 and
   8 x 8) carried back up, and the scores come back to 1/8 with the 1/8 grid's own correlations added: a weakly
   textured region takes the hypothesis of textured surroundings up to ~350 sensor pixels away (a score depends on
   ~690 sensor rows around its cell, ~150 without the coarse levels);
4. a softmax over the hypotheses, and the expected hypothesis within :attr:`StartArchitecture.window` of the best
   one (a multi-modal curve is not averaged across its modes), as s on the reference grid; the probability mass in
   that window is the confidence.

The estimate starts :class:`~prismstereo.learned.hybrid.HybridStereo`'s refinement stages (``HybridArchitecture(
start='learned')``, the default), which runs it on 4 x 4 cells of its stages' grid: 8 x 8 pixels where the stages run
2 x 2-binned, else a rig of twice the sensor's resolution (:meth:`~prismstereo.geometry.rig.BiPrismRig.unbinned`)
whose 2 x 2-binned capture is the capture itself. Training: :mod:`prismstereo.learned.start_train`.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any, NamedTuple

import torch
import torch.nn.functional as F
from torch import nn

from prismstereo.classical.defaults import default_hypotheses
from prismstereo.errors import OptionError, ShapeError, check_int, check_shape
from prismstereo.geometry.optics import check_rig_images
from prismstereo.geometry.rig import BiPrismRig
from prismstereo.nn import PrismCostVolume
from prismstereo.nn.rectified_volume import RectifiedCostVolume

__all__ = ["LEARNED", "SCALE", "START_FORMAT", "START_WEIGHTS", "StartArchitecture", "StartEstimate", "SweepStart",
           "load_start", "windowed_expectation"]

START_WEIGHTS = Path(__file__).resolve().parent / "weights" / "start.pt"
"""The shipped first stage (:mod:`prismstereo.learned.start_train` says how it was trained)."""
START_FORMAT = "prismstereo.start/1"
SCALE = 8
"""The first stage's resolution: features and hypotheses on the sensor binned 8 x 8."""
LEARNED = ("features", "context", "first", "down", "up", "dilated", "head", "fine")
"""The learned layers (what a weights file holds; the volume and masks are built from the rig and range)."""
MASKED = 1e4  # subtracted from the score of a hypothesis that does not sample the other half
SAMPLINGS = ("sweep", "rectified")
AGGREGATIONS = ("fine", "pooled")


@dataclasses.dataclass(frozen=True)
class StartArchitecture:
    """The hyper-parameters that shape the first stage's weights (stored beside them).

    Attributes:
        features: C, channels of the correlated feature map.
        groups: G correlation groups (C must be a multiple of G).
        channels: A, channels of the aggregation's 2-D convolutions.
        window: hypotheses on each side of the best one that the expected s is taken over.
        levels: coarser grids of the aggregation (0: none): each hypothesis' map is pooled 2 x 2 and convolved
            (3 x 3) ``levels`` times, then carried back up level by level (bilinear, added to the finer map; a 3 x 3
            convolution on each coarse level, none on the finest, where the convolutions cost most), so a score sees
            up to 2 ** levels times farther: a weakly textured region takes the hypothesis of its textured
            surroundings.
        aggregation: the grid the aggregation's convolutions work on: ``'fine'`` (the 1/8 grid of the correlation)
            or ``'pooled'`` (the correlation pooled 2 x 2, so the convolutions cost a quarter; its scores carried
            back to 1/8 bilinearly, plus the 1/8 grid's own evidence: the groups' correlations weighted and summed).
        sampling: ``'sweep'`` (hypotheses uniform in s, each sampled bilinearly on its exact sweep:
            :class:`~prismstereo.nn.PrismCostVolume`) or ``'rectified'`` (whole-pixel column shifts on row-rectified
            features, turned into s exactly: :class:`~prismstereo.nn.rectified_volume.RectifiedCostVolume`, several
            times faster exported). The weights belong to one of them.

    Raises:
        OptionError: a value out of its range, or C not a multiple of G.

    Example:
        >>> StartArchitecture().features, StartArchitecture(groups=8).groups
        (16, 8)
    """

    features: int = 16
    groups: int = 4
    channels: int = 8
    window: int = 2
    sampling: str = "rectified"
    levels: int = 2
    aggregation: str = "pooled"

    @classmethod
    def recorded(cls, fields: Any) -> StartArchitecture:
        """The architecture whose fields a weights file records (a hybrid's ``start_architecture``).

        Raises:
            WeightsError: fields that are not a valid architecture.

        Example:
            >>> StartArchitecture.recorded({"channels": 8}).channels
            8
        """
        from prismstereo.learned.weights import WeightsError

        try:
            return cls(**fields)
        except (TypeError, OptionError) as exc:
            raise WeightsError(f"the weights record an invalid first stage architecture {fields!r}: {exc}") from exc

    def __post_init__(self) -> None:
        for name, low, high in (("features", 1, 128), ("groups", 1, 128), ("channels", 1, 64), ("window", 1, 8),
                                ("levels", 0, 4)):
            check_int(getattr(self, name), name, low, most=high)
        if self.aggregation not in AGGREGATIONS:
            raise OptionError(f"Unknown aggregation {self.aggregation!r}. Choose from: {', '.join(AGGREGATIONS)}")
        if self.sampling not in SAMPLINGS:
            raise OptionError(f"Unknown sampling {self.sampling!r}. Choose from: {', '.join(SAMPLINGS)}")
        if self.features % self.groups:
            raise OptionError(f"features ({self.features}) must be a multiple of groups ({self.groups})")


class StartEstimate(NamedTuple):
    """The first stage's estimate on the 8 x 8-binned reference grid (h, w).

    Attributes:
        s: (B, 1, h, w) sweep coordinate in [-1, 1] (0 where not ``covered``).
        confidence: (B, 1, h, w) the probability mass within the window around the best hypothesis (0 where not
            ``covered``).
        covered: (B, 1, h, w) 1 where a hypothesis samples the other half (for 'rectified': of a neighbouring
            rectified pixel), else 0, in ``s``'s dtype.
        scores: (B, D, h', w') the aggregated scores (training's classification target is on them; 'rectified': on
            the rectified grid, transposed); invalid hypotheses lowered by 1e4.
    """

    s: torch.Tensor
    confidence: torch.Tensor
    covered: torch.Tensor
    scores: torch.Tensor


def _conv3(cin: int, cout: int, stride: int = 1, dilation: int = 1) -> nn.Conv2d:
    if stride == 2:  # kernel 4, padding 1: output pixel j centred on input 2 j + 1/2
        return nn.Conv2d(cin, cout, 4, 2, padding=1)
    return nn.Conv2d(cin, cout, 3, padding=dilation, dilation=dilation)


def _feature_net(features: int) -> nn.Sequential:
    """2 x 2-binned normalised capture (B, 2, H/2, W/2) -> (B, C, H/8, W/8)."""
    return nn.Sequential(_conv3(2, 8, 2), nn.ReLU(), _conv3(8, 16), nn.ReLU(),
                         _conv3(16, 16, 2), nn.ReLU(), _conv3(16, 16), nn.ReLU(), _conv3(16, 16, dilation=2),
                         nn.ReLU(), nn.Conv2d(16, features, 1))


class SweepStart(nn.Module):
    """The learned first stage of a rig and range (module docstring).

    Args:
        rig: the full-resolution rig; its sensor size must be divisible by 8.
        z_range: (z_min, z_max) searched, mm.
        architecture: the hyper-parameters (default :class:`StartArchitecture` ()).

    Attributes:
        volume: the correlation on the sensor binned by 8: a
            :class:`~prismstereo.nn.rectified_volume.RectifiedCostVolume` ('rectified') or a
            :class:`~prismstereo.nn.PrismCostVolume` ('sweep').
        values: (D,) buffer, the hypotheses' sweep coordinates ('sweep') or column shifts ('rectified').

    Raises:
        OptionError: a sensor 8 does not divide, or a rig that is not a BiPrismRig. RigError: bad rig or range.

    Example:
        >>> start = SweepStart(thesis_setup1().downscaled(2), (450.0, 1000.0))
        >>> out = start(torch.randn(1, 2, 192, 256))
        >>> out.s.shape, out.scores.shape[1] == start.num_hypotheses
        (torch.Size([1, 1, 48, 32]), True)
    """

    values: torch.Tensor

    def __init__(self, rig: BiPrismRig, z_range: tuple[float, float], *,
                 architecture: StartArchitecture | None = None) -> None:
        super().__init__()
        if not isinstance(rig, BiPrismRig):
            raise OptionError(f"rig must be a BiPrismRig, got {type(rig).__name__}")
        check_rig_images(rig)
        if rig.image_width % SCALE or rig.image_height % SCALE:
            raise OptionError(f"the {rig.image_width}x{rig.image_height} sensor is not divisible by {SCALE}")
        self.architecture = arch = architecture or StartArchitecture()
        self.rig = rig
        self.z_range = (float(z_range[0]), float(z_range[1]))
        self.volume: PrismCostVolume | RectifiedCostVolume
        if arch.sampling == "rectified":
            self.volume = RectifiedCostVolume(rig, self.z_range, SCALE, groups=arch.groups)
            values = self.volume.shifts
        else:
            d = default_hypotheses(rig.binned(SCALE), self.z_range)
            self.volume = PrismCostVolume(rig, self.z_range, d, SCALE, groups=arch.groups)
            values = torch.linspace(-1.0, 1.0, d)
        self.features = _feature_net(arch.features)
        a = arch.channels
        self.context = nn.Conv2d(arch.features, a, 1)
        self.first = nn.Conv2d(arch.groups, a, 3, padding=1)
        self.down = nn.ModuleList([nn.Conv2d(a, a, 3, padding=1) for _ in range(arch.levels)])
        self.up = nn.ModuleList([nn.Conv2d(a, a, 3, padding=1) for _ in range(max(0, arch.levels - 1))])
        self.dilated = nn.Conv2d(a, a, 3, padding=2, dilation=2)
        pooled = arch.aggregation == "pooled"
        self.fine = nn.ModuleList([nn.Conv2d(arch.groups, 1, 1)] if pooled else [])
        self.head = nn.Conv2d(a, 1, 3, padding=1)
        dtype = torch.get_default_dtype()
        # the hypotheses' values: sweep coordinates ('sweep') or shifts ('rectified')
        self.register_buffer("values", values.to(dtype), persistent=False)
        if isinstance(self.volume, RectifiedCostVolume):
            covered = self.volume.covered()
        else:
            covered = self.volume.valid.any(0).view(1, 1, *self.volume.valid.shape[1:])
        self.register_buffer("covered_mask", covered.to(dtype), persistent=False)

    def weights(self) -> dict[str, torch.Tensor]:
        """The learned tensors (:data:`LEARNED` layers), what a weights file holds."""
        return {f"{name}.{k}": v for name in LEARNED for k, v in getattr(self, name).state_dict().items()}

    def load_weights(self, state: dict[str, torch.Tensor]) -> None:
        """Load :meth:`weights` of the same architecture.

        Raises:
            WeightsError: tensors that do not fit the architecture.
        """
        from prismstereo.learned.weights import WeightsError, state_part

        for name in LEARNED:
            try:
                getattr(self, name).load_state_dict(state_part(state, name))
            except RuntimeError as exc:
                raise WeightsError(f"weights do not fit the architecture {self.architecture}: {exc}") from exc

    @property
    def num_hypotheses(self) -> int:
        """D, the hypotheses over the range."""
        return self.volume.num_hypotheses

    @property
    def step(self) -> float:
        """The sweep coordinate between neighbouring hypotheses ('rectified': on average over the range)."""
        return 2.0 / (self.num_hypotheses - 1)

    @property
    def valid(self) -> torch.Tensor:
        """(D, h', w') bool: where each hypothesis samples the other half, on the scores' grid."""
        return self.volume.valid

    def truth_index(self, s: torch.Tensor, known: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """True sweep coordinates ``s`` and ``known`` (B, 1, h, w) on the reference grid as fractional hypothesis
        indices and their known mask on the scores' grid (training's target), (B, 1, h', w') each."""
        if isinstance(self.volume, RectifiedCostVolume):
            return self.volume.truth_shift(s, known)
        return (s + 1.0) / self.step, known

    def scores(self, image: torch.Tensor) -> torch.Tensor:
        """Steps 1-3: (B, D, h, w) aggregated scores of the normalised binned capture ``image`` (B, 2, H/2, W/2);
        hypotheses that do not sample the other half lowered by 1e4."""
        check_shape(image, ["B", 2, "H", "W"], "image")
        rig = self.rig
        if tuple(image.shape[-2:]) != (rig.image_height // 2, rig.image_width // 2):
            raise ShapeError(f"image must be the normalised 2 x 2-binned capture (B, 2, {rig.image_height // 2}, "
                             f"{rig.image_width // 2}), got {tuple(image.shape)}")
        features = self.features(image)
        cost = self.volume(features)  # (B, G, D, h', w'), or (B, D, h', w') with one group
        if cost.dim() == 4:
            cost = cost.unsqueeze(1)
        b, g, d, h, w = cost.shape
        a = self.architecture.channels
        # 2-D convolutions on every hypothesis at once: (B D, channels, h', w')
        c = cost.transpose(1, 2).reshape(b * d, g, h, w)
        if isinstance(self.volume, RectifiedCostVolume):
            reference = self.volume.rectified_reference(features)
        else:
            reference = features[..., :self.volume.reference_width]
        pooled = self.architecture.aggregation == "pooled"
        if pooled:
            c, reference = (F.avg_pool2d(t, 2, ceil_mode=True) for t in (c, reference))
        x = self.first(c)
        hh, ww = x.shape[-2:]
        x = F.relu(x.view(b, d, a, hh, ww) + self.context(reference).unsqueeze(1)).view(b * d, a, hh, ww)
        x = self._coarse(x)
        x = self.head(F.relu(self.dilated(x)))
        if pooled:  # the fine grid's own evidence: the groups' weighted sum (a 1 x 1 convolution)
            fine = self.fine[0]
            own = (cost * fine.weight.view(1, g, 1, 1, 1)).sum(1) + fine.bias
            x = F.interpolate(x, size=(h, w), mode="bilinear", align_corners=False).view(b, d, h, w) + own
        return x.view(b, d, h, w) - (1.0 - self.volume.valid.to(x.dtype)) * MASKED

    def _coarse(self, x: torch.Tensor) -> torch.Tensor:
        """The coarser levels of the aggregation (:attr:`StartArchitecture.levels`) on (B D, A, h, w) maps."""
        finer = []
        for conv in self.down:
            finer.append(x)
            x = F.relu(conv(F.avg_pool2d(x, 2, ceil_mode=True)))
        for i, skip in enumerate(reversed(finer)):
            x = skip + F.interpolate(x, size=skip.shape[-2:], mode="bilinear", align_corners=False)
            if i < len(self.up):
                x = F.relu(self.up[i](x))
        return x

    def forward(self, image: torch.Tensor) -> StartEstimate:
        """The estimate of the normalised 2 x 2-binned capture ``image`` (B, 2, H/2, W/2) (step 4).

        Returns:
            :class:`StartEstimate` on the 8 x 8-binned reference grid.

        Raises:
            ShapeError: an image that is not (B, 2, H/2, W/2) of the rig's sensor.
        """
        scores = self.scores(image)
        value, mass = windowed_expectation(scores, self.values, self.architecture.window)
        if isinstance(self.volume, RectifiedCostVolume):  # shift -> s, rectified grid -> reference grid
            s = self.volume.to_sweep(value)
            s, mass = self.volume.back(torch.cat([s, mass.transpose(-1, -2)], 1)).split(1, 1)
        else:
            s = value
        covered = self.covered_mask.to(scores.dtype).expand(scores.shape[0], -1, -1, -1)
        return StartEstimate(s * covered, mass * covered, covered, scores)


def windowed_expectation(scores: torch.Tensor, values: torch.Tensor, window: int
                         ) -> tuple[torch.Tensor, torch.Tensor]:
    """The expectation of ``values`` under the softmax of ``scores`` over axis 1, restricted to the ``window``
    hypotheses on each side of the best one, and the probability mass there.

    Args:
        scores: (B, D, h, w).
        values: (D,) the hypotheses' values.
        window: hypotheses on each side.

    Returns:
        (value, mass): (B, 1, h, w) each.

    Example:
        >>> scores = torch.tensor([0.0, 5.0, 0.0, 0.0, 4.9]).view(1, 5, 1, 1)  # two modes
        >>> value, mass = windowed_expectation(scores, torch.arange(5.0), 1)
        >>> round(float(value), 3), round(float(mass), 3)  # the stronger mode's, not the mean of both
        (1.0, 0.526)
    """
    # the softmax by hand: onnxruntime's Softmax over a leading axis transposes the volume twice
    top = scores.amax(1, keepdim=True)
    e = torch.exp(scores - top)
    index = torch.arange(scores.shape[1], dtype=scores.dtype, device=scores.device).view(1, -1, 1, 1)
    best = scores.argmax(1, keepdim=True).to(scores.dtype)
    q = e * ((index - best).abs() <= window).to(e.dtype)
    near = q.sum(1, keepdim=True)
    value = (q * values.to(e.dtype).view(1, -1, 1, 1)).sum(1, keepdim=True) / near
    return value, near / e.sum(1, keepdim=True)


def load_start(rig: BiPrismRig, z_range: tuple[float, float], path: str | Path = START_WEIGHTS) -> SweepStart:
    """A :class:`SweepStart` of ``rig`` and ``z_range`` with the weights of ``path`` (written by
    :func:`~prismstereo.learned.start_train.train_start`).

    Raises:
        WeightsError: a file that cannot be read or does not fit.

    Example:
        >>> start = load_start(thesis_setup1(), (228.0, 1374.0))
        >>> start.num_hypotheses
        49
    """
    from prismstereo.learned.weights import read_weights

    arch, state, _ = read_weights(path, START_FORMAT, StartArchitecture, "SweepStart")
    model = SweepStart(rig, z_range, architecture=arch)
    model.load_weights(state)
    return model
