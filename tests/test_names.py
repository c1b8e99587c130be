"""prismstereo.names: the shared choices are one set of objects, whichever module a caller takes them from."""

import prismstereo.io
import prismstereo.models
import prismstereo.predictor
from prismstereo import names


def test_the_owning_modules_re_export_the_same_choices():
    assert prismstereo.models.MODEL_KINDS is names.MODEL_KINDS == ("hybrid", "classical", "learned")
    assert prismstereo.predictor.BACKENDS is names.BACKENDS == ("torch", "onnx")
    assert prismstereo.io.DEPTH_FILE_FORMATS is names.DEPTH_FILE_FORMATS
    assert set(names.DEPTH_SUFFIXES.values()) == set(names.DEPTH_FILE_FORMATS)
    assert prismstereo.io.DEPTH_SUFFIXES is names.DEPTH_SUFFIXES
