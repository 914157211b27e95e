"""Uncertainty of the lighting fit L-hat and the choice of lighting model order."""
from disent.lighting.posterior import (  # noqa: F401
    N_COEFFS, LightingData, LogPosterior, Posterior, gaussian_posterior, prepare, sample_posterior,
)
