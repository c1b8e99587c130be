"""prismstereo: metric stereo depth from one camera with a bi-prism, as differentiable torch layers.

The names a user starts from (conventions: :mod:`prismstereo.conventions`):

* the rig: :class:`BiPrismRig` (JSON with :meth:`~BiPrismRig.to_json` / :meth:`~BiPrismRig.from_json`),
  :func:`load_rig` (a rig file, JSON text, dict or preset name, geometry checked), :func:`thesis_setup1`,
  :func:`thesis_setup2`;
* depth: :func:`build_model` (the one builder: the rig's default, or ``kind`` 'hybrid', 'classical', 'learned'),
  every model a :class:`DepthModel` with one output, :class:`DepthResult`; the models :class:`HybridStereo` (the
  default on large sensors), :class:`PrismStereo` (the classical chain, its options :class:`StereoConfig` with the
  named :data:`PRESETS`, :func:`preset`) and :class:`LearnedStereo`; :func:`to_grey`, the one grey rule;
* running them: :class:`Predictor` (a model in torch or its exported graphs in onnxruntime, one set of calls),
  :func:`export_onnx` and :class:`OnnxDepth` (a graph in onnxruntime), :class:`DepthStream` (frames pushed one at a
  time) with :class:`TemporalOptions`;
* files: :func:`read_image`, :func:`write_depth`, :func:`read_depth`;
* errors: :class:`PrismStereoError` and its family.

Everything else lives in the subpackages, along the data path: :mod:`prismstereo.geometry` (exact optics, virtual
cameras) -> :mod:`prismstereo.epipolar` -> :mod:`prismstereo.matching` -> :mod:`prismstereo.depth` -> the models
(:mod:`prismstereo.classical`, :mod:`prismstereo.learned`; :mod:`prismstereo.models`) -> :mod:`prismstereo.predictor`
-> :mod:`prismstereo.export`, :mod:`prismstereo.stream`, :mod:`prismstereo.jobs`, :mod:`prismstereo.cli`; beside
them :mod:`prismstereo.calibration`, :mod:`prismstereo.analysis`, :mod:`prismstereo.synthetic`,
:mod:`prismstereo.nn`. The names are imported on first use, so ``import prismstereo`` stays light (it does not
import torch).
"""

from prismstereo.errors import CalibrationError, OptionError, PrismStereoError, RigError, ShapeError
from prismstereo.lazy import lazy_names

__version__ = "0.1.0"

__all__ = [
    "__version__",
    "PrismStereoError",
    "RigError",
    "ShapeError",
    "OptionError",
    "CalibrationError",
    "BiPrismRig",
    "load_rig",
    "thesis_setup1",
    "thesis_setup2",
    "build_model",
    "DepthModel",
    "ModelSpec",
    "HybridStereo",
    "PrismStereo",
    "StereoConfig",
    "PRESETS",
    "preset",
    "DepthResult",
    "LearnedStereo",
    "to_grey",
    "Predictor",
    "export_onnx",
    "OnnxDepth",
    "DepthStream",
    "TemporalOptions",
    "read_image",
    "write_depth",
    "read_depth",
]

_LAZY = {
    "BiPrismRig": "prismstereo.geometry.rig",
    "load_rig": "prismstereo.geometry.presets",
    "thesis_setup1": "prismstereo.geometry.presets",
    "thesis_setup2": "prismstereo.geometry.presets",
    "build_model": "prismstereo.models",
    "DepthModel": "prismstereo.models",
    "ModelSpec": "prismstereo.models",
    "HybridStereo": "prismstereo.learned",
    "to_grey": "prismstereo.conventions",
    "Predictor": "prismstereo.predictor",
    "PrismStereo": "prismstereo.classical.model",
    "StereoConfig": "prismstereo.classical.config",
    "PRESETS": "prismstereo.classical.config",
    "preset": "prismstereo.classical.config",
    "DepthResult": "prismstereo.depth.result",
    "LearnedStereo": "prismstereo.learned",
    "export_onnx": "prismstereo.export",
    "OnnxDepth": "prismstereo.export",
    "DepthStream": "prismstereo.stream",
    "TemporalOptions": "prismstereo.classical.prior",
    "read_image": "prismstereo.io",
    "write_depth": "prismstereo.io",
    "read_depth": "prismstereo.io",
}


__getattr__, __dir__ = lazy_names(__name__, _LAZY, __all__)
