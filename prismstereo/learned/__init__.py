"""A small learned depth model on the exact prism sweep, its training data and its trainer."""

from prismstereo.learned.data import KINDS, TrainingSet, procedural_picture, random_capture_spec, training_set
from prismstereo.learned.network import (
    DEFAULT_WEIGHTS,
    HYPOTHESIS_SPACING_PX,
    Architecture,
    LearnedStereo,
    WeightsError,
    learned_hypotheses,
    load_weights,
)
from prismstereo.learned.train import TrainResult, train

__all__ = [
    "DEFAULT_WEIGHTS",
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
