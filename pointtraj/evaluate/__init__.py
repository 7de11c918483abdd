"""Evaluation: the paper's three studies, ground-truth metrics, and the report."""

from __future__ import annotations

from .metrics import (
    LabelAccuracy,
    agreement_rate,
    disagreement_by_distance,
    label_accuracy,
)
from .report import Section, write_report
from .study import EvaluateConfig, evaluate_work

__all__ = [
    "EvaluateConfig",
    "evaluate_work",
    "LabelAccuracy",
    "Section",
    "agreement_rate",
    "disagreement_by_distance",
    "label_accuracy",
    "write_report",
]
