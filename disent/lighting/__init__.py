"""Uncertainty of the lighting fit L-hat (an emcee posterior) and the choice of its model order.

``python -m disent.lighting`` (conf/lighting.yaml) samples the posterior of one image or a
split; ``python -m disent.bench lighting`` times the least-squares fit and the posterior.
"""
from disent.lighting.order import select_order
from disent.lighting.posterior import (
    N_COEFFS, LightingData, LogPosterior, Posterior, gaussian_posterior, prepare, sample_posterior,
)
from disent.lighting.texture import TextureModel, texture_model

__all__ = ["select_order", "N_COEFFS", "LightingData", "LogPosterior", "Posterior", "gaussian_posterior", "prepare",
           "sample_posterior", "TextureModel", "texture_model", "bench_lighting"]


def bench_lighting(args) -> dict:
    """L-hat by least squares (batched, per image) and the posterior (27 parameters, 64x64)."""
    from disent.bench import print_table
    from disent.lighting.experiments import speed
    from disent.lighting.threads import single_core

    with single_core():  # the posterior's target is one core (torch and BLAS threads)
        out = speed(batch=args.batch, rounds=args.rounds)
    print_table(f"lighting: L-hat least squares (batch {out['ls_batch']}) and emcee posterior "
                f"({out['n_pixels']} face pixels at 64x64, 1 thread)", out)
    return out


def _register() -> None:
    from disent.bench import register

    register("lighting", bench_lighting)


_register()
