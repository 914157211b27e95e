"""Ship a finished run's weights inside the package (``disent/weights/``), and score shipped weights with this
version's metrics: ``python -m disent.models.shipped RUN_DIR NAME`` and ``... NAME --add-metrics`` (or ``python -m
disent.ship``).  Reading them is :mod:`disent.models.shipped`."""

from __future__ import annotations

import argparse
import hashlib
import json
from pathlib import Path

import torch

from disent.models.shipped import CHECK_IMAGES, CHECK_KEYS, WEIGHTS, load_weights, manifest, shipped_path


def check_metrics(model, cfg, n: int = CHECK_IMAGES) -> dict:
    """The ``CHECK_KEYS`` metrics of ``model`` on the first ``n`` test images of its data set."""
    from disent.data import make_dataset
    from disent.eval.evaluate import evaluate_model

    test = make_dataset(cfg.data, "test", cfg.data.get("test_size"), device="cpu")
    m = evaluate_model(model, test, limit=n)
    return {k: m[k] for k in CHECK_KEYS if k in m}


def ship(run_dir, name: str, folder: Path = WEIGHTS) -> dict:
    """Write run ``run_dir``'s final weights as shipped model ``name`` and its manifest entry."""
    from omegaconf import OmegaConf

    from disent.models import build_model
    from disent.runs import Run
    from disent.storage import load_checkpoint, machine_info

    run_dir, folder = Path(run_dir), Path(folder)
    ckpt = load_checkpoint(run_dir / "checkpoints" / "last.pt")
    eval_path = run_dir / "eval.json"
    if not eval_path.exists():
        raise FileNotFoundError(f"{run_dir} has no eval.json: only a finished, evaluated run can be shipped")
    half = {k: (v.half() if v.is_floating_point() else v) for k, v in ckpt["model"].items()}
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{name}.pt"
    torch.save({"cfg": ckpt["cfg"], "model": half}, path)
    cfg = OmegaConf.create(ckpt["cfg"])
    model = build_model(cfg.model)
    load_weights(model, half, path)
    metrics = json.loads(eval_path.read_text())
    entry = {
        "file": path.name,
        "bytes": path.stat().st_size,
        "sha256": hashlib.sha256(path.read_bytes()).hexdigest(),
        "run": str(run_dir),
        "git": (run_dir / "git.txt").read_text() if (run_dir / "git.txt").exists() else None,
        "steps": ckpt["step"],
        "train_seconds": ckpt["wall"],
        "images": ckpt["step"] * cfg.train.batch_size,
        "machine": Run.load(run_dir).machine or machine_info(cfg.device, cfg.train.threads),  # where it trained
        "metrics": metrics,
        "check": check_metrics(model.eval(), cfg),
        "check_images": CHECK_IMAGES,
        "cfg": ckpt["cfg"],
    }
    entries = manifest(folder)
    entries[name] = entry
    (folder / "manifest.json").write_text(json.dumps(entries, indent=1, sort_keys=True) + "\n")
    return entry


def add_metrics(name: str, folder: Path = WEIGHTS) -> list[str]:
    """Score shipped model ``name`` with this version's metrics (:func:`disent.eval.evaluate.score`) and add to its
    manifest entry the metrics its run's ``eval.json`` lacks; those it has stay as the run scored them (float32
    weights). The added ones come from the shipped float16 weights, and ``metrics_added`` says which (``keys``) and,
    per addition, at what revision (``additions``). Returns the added keys."""
    from disent.eval.evaluate import score
    from disent.storage import git_revision

    path = shipped_path(name, folder)  # an unknown name: the error that lists the shipped names
    entries = manifest(folder)
    metrics = entries[name]["metrics"]
    new = score(path)
    added = sorted(k for k in new if k not in metrics)
    metrics.update({k: new[k] for k in added})
    if added:
        before = entries[name].get("metrics_added", {})
        additions = before.get("additions") or ([{"git": before["git"], "keys": before["keys"]}] if before else [])
        entries[name]["metrics_added"] = {
            "keys": sorted({*before.get("keys", []), *added}),
            "additions": [*additions, {"git": git_revision(), "keys": added}],
            "weights": "float16",
        }
        (Path(folder) / "manifest.json").write_text(json.dumps(entries, indent=1, sort_keys=True) + "\n")
    return added


def main(argv=None):
    p = argparse.ArgumentParser(description="Ship a finished run's weights inside the package (disent/weights/).")
    p.add_argument("run", help="run folder with checkpoints/last.pt and eval.json (with --add-metrics: a shipped name)")
    p.add_argument("name", nargs="?", help="name to load it by: load_run(NAME), python -m disent.edit relight NAME ...")
    p.add_argument("--folder", type=Path, default=WEIGHTS, help="where the weights and manifest.json go")
    p.add_argument(
        "--add-metrics",
        action="store_true",
        help="score the shipped model RUN with this version's metrics and add those its manifest lacks",
    )
    a = p.parse_args(argv)
    torch.set_num_threads(1)
    if a.add_metrics:
        print(f"{a.run}: added {', '.join(add_metrics(a.run, a.folder)) or 'nothing (every metric was there)'}")
        return
    if a.name is None:
        p.error("give the NAME to ship the run as")
    e = ship(a.run, a.name, a.folder)
    print(
        f"shipped {a.name}: {e['bytes'] / 1e6:.1f} MB, {e['steps']} steps, "
        f"check on {CHECK_IMAGES} test images {e['check']}"
    )


if __name__ == "__main__":
    main()
