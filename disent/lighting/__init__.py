"""Uncertainty of the lighting fit L-hat (an emcee posterior) and the choice of its model order.

``python -m disent.lighting`` (conf/lighting.yaml) samples the posterior of one image or a
split; ``python -m disent.bench lighting`` (:mod:`disent.bench.lighting`) times the least-squares fit and the posterior.
"""

from disent.lighting.order import select_order
from disent.lighting.posterior import (
    N_COEFFS,
    LightingData,
    LogPosterior,
    Posterior,
    gaussian_posterior,
    prepare,
    sample_posterior,
)
from disent.lighting.texture import TextureModel, texture_model

__all__ = [
    "select_order",
    "N_COEFFS",
    "LightingData",
    "LogPosterior",
    "Posterior",
    "gaussian_posterior",
    "prepare",
    "sample_posterior",
    "TextureModel",
    "texture_model",
]
