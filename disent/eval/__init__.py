"""Evaluation: metrics (:mod:`disent.eval.metrics`, re-exported here), protocols and stability studies."""

from disent.eval import metrics as _metrics
from disent.eval.metrics import *  # noqa: F403  (exactly metrics.__all__)

__all__ = list(_metrics.__all__)
