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


def test_the_hybrid_and_the_depth_parser_share_the_last_stages_and_the_graphs_their_names():
    import prismstereo.export.graph
    import prismstereo.learned.hybrid
    from prismstereo.cli import build_parser

    assert prismstereo.learned.hybrid.LAST_STAGES is names.LAST_STAGES == ("exact", "learned")
    depth = build_parser(["depth"])._subparsers._group_actions[0].choices["depth"]
    assert next(a for a in depth._actions if a.dest == "last_stage").choices is names.LAST_STAGES
    assert prismstereo.export.graph.OUTPUT_NAMES is names.OUTPUT_NAMES == ("depth_mm", "valid", "confidence")
    assert prismstereo.export.graph.PRIOR_NAMES is names.PRIOR_NAMES
