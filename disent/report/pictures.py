"""The test batch the report's pictures show (image grids: :func:`disent.images.image_grid`)."""

from __future__ import annotations


def test_batch(n: int, resolution: int = 64):
    """The first ``n`` SynthFaces test faces, with every layer of their truth."""
    from disent.data import SynthFaces
    from disent.eval.scoring import batches

    return next(iter(batches(SynthFaces(split="test", resolution=resolution, seed=0), n, n)))
