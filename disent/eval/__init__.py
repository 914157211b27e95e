"""Evaluation: metrics (:mod:`disent.eval.metrics`), protocols and stability studies."""

from disent.eval.metrics import (
    ANGLE_THRESHOLDS,
    angular_error_deg,
    normal_angular_error,
    optimal_scale,
    reconstruction_metrics,
    scale_invariant_mse,
    sh_error,
)

__all__ = [
    "angular_error_deg",
    "normal_angular_error",
    "reconstruction_metrics",
    "scale_invariant_mse",
    "sh_error",
    "optimal_scale",
    "ANGLE_THRESHOLDS",
]
