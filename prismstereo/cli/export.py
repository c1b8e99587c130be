"""``prismstereo export``: the ONNX graph of the depth model the flags ask for (the flags of ``prismstereo depth``),
written from the cache of exported graphs (:func:`~prismstereo.export.cached_graphs`): a request exported before,
by ``depth --backend onnx`` or an earlier export, is copied without building the model."""

from __future__ import annotations

import argparse
import shutil
import time
from pathlib import Path

from prismstereo.cli.model_flags import add_model_arguments, flag_errors, model_spec, range_note
from prismstereo.errors import PrismStereoError
from prismstereo.geometry.presets import load_rig

__all__ = ["add_parser"]


def _cmd_export(args: argparse.Namespace) -> int:
    from prismstereo.export import OnnxDepth, cached_graphs, describe_graph
    from prismstereo.io import replacing

    out = Path(args.out)
    if out.suffix.lower() != ".onnx":
        raise PrismStereoError(f"--out must end in .onnx, got {out}")
    spec = model_spec(args, load_rig(args.rig))
    t0 = time.perf_counter()
    with flag_errors(args):
        files = cached_graphs(spec, channels=args.channels, opset=args.opset)
    seconds = time.perf_counter() - t0
    graph = OnnxDepth(files.path)  # proves the file loads in onnxruntime with all graph optimisations
    print(f"{range_note(args, graph.z_range)}, {files.summary}" + (" (cached graph)" if files.cached else ""))
    t0 = time.perf_counter()
    with replacing(out) as partial:  # the cached file, copied whole
        shutil.copyfile(files.path, partial)
    how = (f"copied from the cache in {time.perf_counter() - t0:.1f} s" if files.cached
           else f"exported in {seconds:.1f} s")
    print(f"wrote {out} ({out.stat().st_size / 1e6:.1f} MB, {how}, onnxruntime load {graph.load_seconds:.1f} s): "
          f"{describe_graph(graph.metadata)}")
    return 0


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Register ``prismstereo export`` on the main parser's subcommands."""
    from prismstereo.export import DEFAULT_OPSET

    export = sub.add_parser("export", help="export the depth model of a rig to ONNX (for onnxruntime)")
    export.add_argument("--rig", required=True, help="rig JSON file or preset name")
    export.add_argument("--out", required=True, help="the .onnx file to write")
    add_model_arguments(export)
    export.add_argument("--opset", type=int, default=DEFAULT_OPSET, metavar="K",
                        help=f"ONNX opset (16-20, default {DEFAULT_OPSET})")
    export.add_argument("--channels", type=int, choices=(1, 3), default=1,
                        help="input channels of the graph (default 1: grey, as `prismstereo depth` feeds it)")
    export.set_defaults(func=_cmd_export)
