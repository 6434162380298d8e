"""Evaluation: tracking vs ground truth, geometry (chamfer, IoU), open-loop dynamics (method-notes §8).

The only code that reads a session's ``ground_truth/``. Entry point: :func:`run`.
"""

from service.evaluation.ground_truth import GroundTruth, load_ground_truth
from service.evaluation.run import run
from service.evaluation.types import METHODS, EvaluationConfig, EvaluationInputs, EvaluationOutputs

__all__ = ["run", "load_ground_truth", "GroundTruth", "EvaluationConfig", "EvaluationInputs", "EvaluationOutputs",
           "METHODS"]
