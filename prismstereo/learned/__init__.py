"""Learned depth on the exact prism sweep: a small cost-volume model (LearnedStereo) and the hybrid of the classical
block level with a learned 2-D refinement (HybridStereo); their training data and trainers."""

from prismstereo.learned.data import KINDS, TrainingSet, procedural_picture, random_capture_spec, training_set
from prismstereo.learned.hybrid import HYBRID_WEIGHTS, HybridStereo
from prismstereo.learned.network import (
    HYPOTHESIS_SPACING_PX,
    LEARNED_WEIGHTS,
    Architecture,
    LearnedStereo,
    learned_hypotheses,
    load_weights,
)
from prismstereo.learned.refinement import HybridArchitecture
from prismstereo.learned.train import TrainResult, train
from prismstereo.learned.weights import WeightsError

__all__ = [
    "HYBRID_WEIGHTS",
    "HybridArchitecture",
    "HybridStereo",
    "LEARNED_WEIGHTS",
    "HYPOTHESIS_SPACING_PX",
    "Architecture",
    "LearnedStereo",
    "WeightsError",
    "learned_hypotheses",
    "load_weights",
    "KINDS",
    "TrainingSet",
    "procedural_picture",
    "random_capture_spec",
    "training_set",
    "TrainResult",
    "train",
]
