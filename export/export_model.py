"""Export the bi-prism depth model of a rig to ONNX: a thin entry point over ``prismstereo.export``.

Same arguments and defaults as ``prismstereo export`` (see README.md in this folder):

    .venv/bin/python export/export_model.py --rig thesis_setup1 --out model.onnx [--z-range ZMIN ZMAX]
        [--hypotheses N] [--opset K] [--channels 1|3]
"""

from __future__ import annotations

import sys

from prismstereo.cli import main

if __name__ == "__main__":
    sys.exit(main(["export", *sys.argv[1:]]))
