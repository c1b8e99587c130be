"""ONNX export of a depth model: the per-frame graph and the temporal band's graph, with the metadata that names them.

The graph (:func:`export_onnx`):

* input ``image``: (B, C, H, W) float32 in [0, 1], the full sensor image; B dynamic, C (1 or 3), H and W static
  (the rig's sensor).
* outputs ``depth_mm`` (B, 1, H, W_ref) float32, ``valid`` (B, 1, H, W_ref) bool, ``confidence`` (B, 1, H, W_ref)
  float32 in [0, 1] — the reference (left) half, W_ref = the columns left of the split.
* ``metadata_props`` (:func:`graph_metadata`): ``prismstereo.version``, ``prismstereo.source``, ``prismstereo.rig``
  (the rig's JSON), ``prismstereo.config`` (the model's :meth:`describe`: kind, range, hypotheses, options),
  ``prismstereo.num_hypotheses``, ``prismstereo.z_range_mm``, ``prismstereo.input_shape``, ``prismstereo.opset``.

The temporal graph (``export_onnx(model, path, temporal=TemporalOptions())``, :class:`TemporalGraph`) is the band
the model offers for videos (its ``tracker``: :class:`~prismstereo.classical.TemporalDepth`; the hybrid's is the
classical model's). It also takes the band's prior :data:`PRIOR_NAMES` (``prior_inverse_depth`` float32 and
``prior_placed`` bool, (B, 1, h, w): a :class:`~prismstereo.classical.BandPrior` at the band's resolution) and also
returns the next frame's, :data:`NEXT_PRIOR_NAMES`; its options (``downsample`` resolved) are in
``prismstereo.temporal``.

Everything a model precomputes for a rig (the exact sweep polynomials, the prism masks, hypotheses) is stored as
constants, so a graph is specific to one rig, sensor size, range and option set. Exported with the TorchScript-based
exporter (``dynamo=False``) at opset 18: it traces the model once; the semi-global aggregation's scan loops are
unrolled (one step per coarse row / column and direction). :mod:`prismstereo.export.session` runs a graph,
:mod:`prismstereo.export.cache` keeps them.
"""

from __future__ import annotations

import functools
import json
import warnings
from pathlib import Path
from typing import TYPE_CHECKING

import torch
from torch import nn

from prismstereo.errors import ExportError
from prismstereo.export.index import DEFAULT_OPSET, describe_graph, source_digest
from prismstereo.names import INPUT_NAME, NEXT_PRIOR_NAMES, OUTPUT_NAMES, PRIOR_NAMES

if TYPE_CHECKING:
    from prismstereo.classical import TemporalDepth, TemporalOptions

__all__ = ["DEFAULT_OPSET", "NEXT_PRIOR_NAMES", "PRIOR_NAMES", "DepthGraph", "ExportError", "TemporalGraph",
           "describe_graph", "export_onnx", "graph_metadata", "source_digest"]



class DepthGraph(nn.Module):
    """The exported computation: a depth model (:class:`~prismstereo.models.DepthModel`) reduced to its three graph
    outputs ``(depth_mm, valid, confidence)``.

    Example:
        >>> from prismstereo.classical.model import PrismStereo
        >>> graph = DepthGraph(PrismStereo(thesis_setup1().downscaled(8), (400.0, 700.0)))
        >>> [t.shape for t in graph(torch.rand(1, 1, 96, 128))][0]
        torch.Size([1, 1, 96, 64])
    """

    def __init__(self, model: nn.Module) -> None:
        super().__init__()
        self.model = model

    def forward(self, image: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        result = self.model(image)
        return result.depth, result.valid, result.confidence


class TemporalGraph(nn.Module):
    """The exported temporal computation: :meth:`~prismstereo.classical.temporal.TemporalDepth.track` with the inputs
    ``(image, prior_inverse_depth, prior_placed)`` (a :class:`~prismstereo.classical.prior.BandPrior`) and the
    outputs ``(depth_mm, valid, confidence, next_inverse_depth, next_placed)``.

    Example:
        >>> from prismstereo.classical.temporal import TemporalDepth
        >>> from prismstereo.classical.model import PrismStereo
        >>> model = PrismStereo(thesis_setup1().downscaled(8), (400.0, 700.0), {"coarse_factor": 2})
        >>> tracker = TemporalDepth(model); image = torch.rand(1, 1, 96, 128)
        >>> TemporalGraph(tracker)(image, *tracker.band_prior(*model(image)[:3]))[0].shape
        torch.Size([1, 1, 96, 64])
    """

    def __init__(self, tracker: nn.Module) -> None:
        super().__init__()
        self.tracker = tracker

    def forward(self, image: torch.Tensor, prior_inverse: torch.Tensor,
                prior_placed: torch.Tensor) -> tuple[torch.Tensor, ...]:
        from prismstereo.classical.prior import BandPrior

        result, following = self.tracker.track(image, BandPrior(prior_inverse, prior_placed))
        return result.depth, result.valid, result.confidence, following.inverse, following.placed


@functools.cache
def graph_metadata(model: nn.Module, channels: int, opset: int, tracker: TemporalDepth | None = None
                   ) -> dict[str, str]:
    """The ``prismstereo.*`` metadata of ``model``'s graph (the module docstring), or with ``tracker`` of its
    temporal band's graph (its options, ``downsample`` resolved, as ``prismstereo.temporal``).

    Example:
        >>> from prismstereo.classical import PrismStereo
        >>> graph_metadata(PrismStereo(thesis_setup1().downscaled(16), (400.0, 700.0)), 1, 18)["prismstereo.opset"]
        '18'
    """
    from prismstereo import __version__

    rig = model.rig
    described = model.describe()
    meta = {
        "prismstereo.version": __version__,
        "prismstereo.source": source_digest(),
        "prismstereo.rig": json.dumps(rig.to_dict(), sort_keys=True),
        "prismstereo.config": json.dumps(described, sort_keys=True),
        "prismstereo.num_hypotheses": str(described["num_hypotheses"]),
        "prismstereo.z_range_mm": json.dumps(described["z_range_mm"]),
        "prismstereo.input_shape": json.dumps(["B", channels, rig.image_height, rig.image_width]),
        "prismstereo.opset": str(opset),
    }
    if tracker is not None:
        meta["prismstereo.temporal"] = json.dumps(tracker.options.to_dict(), sort_keys=True)
    return meta


def export_onnx(model: nn.Module, path: str | Path, *, channels: int = 1, opset: int = DEFAULT_OPSET,
                temporal: TemporalOptions | TemporalDepth | None = None) -> Path:
    """Export a depth model (:class:`~prismstereo.models.DepthModel`) to an ONNX file, checked with ``onnx.checker``.

    Args:
        model: the model (its rig, range and options are baked into the graph).
        path: the ``.onnx`` file to write (parent directories are created).
        channels: C of the graph's input, 1 (grey) or 3 (RGB; the graph takes its grey by the models' rule).
        opset: ONNX opset, 16-20 (GridSample needs 16).
        temporal: None (the per-frame graph) or :class:`~prismstereo.classical.TemporalOptions`: the temporal
            graph of the band the model offers for videos (:class:`TemporalGraph`; the inputs ``image`` and
            :data:`PRIOR_NAMES`, the outputs and :data:`NEXT_PRIOR_NAMES`), run next to the per-frame one by
            :class:`~prismstereo.predictor.Predictor` (or the band, :meth:`model.tracker(options)
            <prismstereo.models.DepthModel.tracker>`, when built already).

    Returns:
        The written path.

    Raises:
        ExportError: not a depth model, bad channels / opset, a temporal graph of a model without a band, or the
            exporter or the checker failed.

    Example:
        >>> from prismstereo.classical import PrismStereo
        >>> import tempfile; out = Path(tempfile.mkdtemp()) / "m.onnx"
        >>> export_onnx(PrismStereo(thesis_setup1().downscaled(16), (400.0, 700.0)), out).exists()
        True
    """
    from prismstereo.models import DepthModel

    if not isinstance(model, nn.Module) or not isinstance(model, DepthModel):
        raise ExportError(f"model must be a depth model (prismstereo.models.DepthModel), got {type(model).__name__}")
    if channels not in (1, 3):
        raise ExportError(f"channels must be 1 or 3, got {channels!r}")
    if not isinstance(opset, int) or not 16 <= opset <= 20:
        raise ExportError(f"opset must be an int in 16..20 (GridSample needs >= 16), got {opset!r}")
    rig = model.rig
    example = torch.rand(1, channels, rig.image_height, rig.image_width, generator=torch.Generator().manual_seed(0))
    tracker = None if temporal is None else _tracker(model, temporal)
    if tracker is None:
        graph, inputs = DepthGraph(model).eval(), (example,)
        names, outputs, prior_size = [INPUT_NAME], list(OUTPUT_NAMES), None
    else:
        graph = TemporalGraph(tracker).eval()
        with torch.no_grad():
            inputs = (example, *tracker.band_prior(*tracker.model(example)[:3]))
        names, outputs = [INPUT_NAME, *PRIOR_NAMES], [*OUTPUT_NAMES, *NEXT_PRIOR_NAMES]
        prior_size = tracker.prior_size
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with warnings.catch_warnings(), torch.no_grad():
        warnings.simplefilter("ignore")  # tracer warnings about Python ints: shapes are static by design
        try:
            torch.onnx.export(graph, inputs, str(path), opset_version=opset, input_names=names,
                              output_names=outputs, dynamo=False,
                              dynamic_axes={n: {0: "batch"} for n in names + outputs})
        except Exception as exc:  # the exporter raises many types; report them as one
            raise ExportError(f"ONNX export failed: {exc}") from exc
    _finish(path, graph_metadata(model if tracker is None else tracker.model, channels, opset, tracker),
            (rig.image_height, rig.reference_width), prior_size)
    return path


def _tracker(model: nn.Module, temporal: TemporalOptions | TemporalDepth) -> TemporalDepth:
    """The band ``model`` offers for videos with ``temporal``'s options (an ExportError if it offers none), or the
    band ``temporal`` itself (a caller that built it already)."""
    from prismstereo.classical import TemporalOptions
    from prismstereo.classical.temporal import TemporalDepth
    from prismstereo.errors import OptionError

    if isinstance(temporal, TemporalDepth):
        return temporal.eval()
    if not isinstance(temporal, TemporalOptions):
        raise ExportError(f"temporal must be None, TemporalOptions or a TemporalDepth, got {type(temporal).__name__}")
    try:
        tracker = model.tracker(temporal)
    except OptionError as exc:
        raise ExportError(f"no temporal graph for this model: {exc}") from exc
    if tracker is None:
        raise ExportError(f"no temporal graph for this model: {model.summary()} has no band to place on the "
                          "previous frame")
    return tracker.eval()


def _finish(path: Path, metadata: dict[str, str], size: tuple[int, int], prior_size: tuple[int, int] | None) -> None:
    """Declare the outputs' shapes exactly (the exporter's shape inference names their height axis after the batch
    axis), add the metadata, check and save the exported file."""
    import onnx

    proto = onnx.load(str(path))
    for output in proto.graph.output:
        dims = output.type.tensor_type.shape.dim
        del dims[:]
        h, w = prior_size if output.name in NEXT_PRIOR_NAMES else size
        for extent in ("batch", 1, h, w):
            dim = dims.add()
            if isinstance(extent, str):
                dim.dim_param = extent
            else:
                dim.dim_value = extent
    for key, value in metadata.items():
        entry = proto.metadata_props.add()
        entry.key, entry.value = key, value
    try:
        onnx.checker.check_model(proto)
    except onnx.checker.ValidationError as exc:
        raise ExportError(f"exported graph fails onnx.checker: {exc}") from exc
    onnx.save(proto, str(path))
