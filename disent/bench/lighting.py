"""``python -m disent.bench lighting``: the least-squares fit L-hat and the emcee posterior, timed on one core."""

from __future__ import annotations


def bench_lighting(args) -> dict:
    """L-hat by least squares (batched, per image) and the posterior (27 parameters, 64x64)."""
    from disent.bench import print_table
    from disent.lighting.experiments import speed
    from disent.runtime import single_core

    with single_core():  # the posterior's target is one core (torch and BLAS threads)
        out = speed(batch=args.batch, rounds=args.rounds)
    print_table(
        f"lighting: L-hat least squares (batch {out['ls_batch']}) and emcee posterior "
        f"({out['n_pixels']} face pixels at 64x64, 1 thread)",
        out,
    )
    return out
