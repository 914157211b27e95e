"""``python -m disent.bench.suite ROOT START END [--into BENCH_JSON]``: a slice of the long-rung suite, timed.

The runs under ``ROOT`` (``ablations/suite_gpu.sh ROOT``, started at unix time ``START`` and ended at ``END``, as
``ablations/gpu_check.sh`` runs them) give the images trained per second of wall time, end to end: process start,
set-up, rendering, training and evaluation all inside it.  At that rate the 33 long runs (250,000 images each) take
``suite_projected_min`` minutes.  ``--into`` adds these figures as the ``suite`` section of a benchmark file (the
report's benchmarks page reads it).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

SUITE_RUNS, RUN_IMAGES = 33, 250_000  # the 11 settings at 3 seeds; +experiment=long's budget


def slice_figures(root: Path, start: float, end: float) -> dict:
    """Each finished run's steps, batch, training seconds and test normals and PSNR; their images per wall second;
    the suite's projected minutes at that rate."""
    from disent.storage import load_json, load_yaml

    runs = []
    for ev_path in sorted(Path(root).glob("*/eval.json")):
        cfg, ev = load_yaml(ev_path.parent / ".hydra" / "config.yaml"), load_json(ev_path)
        runs.append(
            {
                "run": ev_path.parent.name,
                "steps": ev["steps"],
                "batch": cfg["train"]["batch_size"],
                "train_seconds": ev["train_seconds"],
                "normal_mean": ev.get("normal_mean"),
                "recon_face_psnr": ev.get("recon_face_psnr"),
            }
        )
    images, wall = sum(r["steps"] * r["batch"] for r in runs), end - start
    rate = images / wall if wall > 0 else 0.0
    return {
        "runs": runs,
        "images": images,
        "wall_s": wall,
        "images_per_s": rate,
        "suite_images": SUITE_RUNS * RUN_IMAGES,
        "suite_projected_min": SUITE_RUNS * RUN_IMAGES / rate / 60 if rate else None,
    }


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(prog="python -m disent.bench.suite", description=__doc__.split("\n\n")[0])
    ap.add_argument("root", type=Path, help="the slice's run folders (ablations/suite_gpu.sh ROOT)")
    ap.add_argument("start", type=float, help="unix time the slice started")
    ap.add_argument("end", type=float, help="unix time it ended")
    ap.add_argument("--into", type=Path, default=None, help="a benchmark JSON to add the figures to, as 'suite'")
    a = ap.parse_args(argv)
    figures = slice_figures(a.root, a.start, a.end)
    print(json.dumps(figures, indent=1))
    if a.into is not None and a.into.is_file():
        a.into.write_text(json.dumps(json.loads(a.into.read_text()) | {"suite": figures}, indent=1))


if __name__ == "__main__":
    main()
