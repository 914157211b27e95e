"""Trained weights shipped inside the package, so that every tool works on a trained model from a fresh install.

``disent/weights/<name>.pt`` holds a float16 state dict and the run's resolved config;
``disent/weights/manifest.json`` holds, per name: the file's size and SHA-256, the run's config, git
revision, test metrics (its ``eval.json``), training steps and seconds, the machine it trained on, and
``check``: metrics of the shipped (float16) weights on the first ``CHECK_IMAGES`` test images, which
``tests/test_shipped.py`` recomputes.

    python -m disent.models.shipped RUN_DIR NAME     # ship a finished run as NAME
    python -m disent.models.shipped NAME --add-metrics   # score it with this version's metrics, add what it lacks
    load_run("explicit")                             # disent.models.load_run takes a shipped name
"""

from __future__ import annotations

import argparse
import hashlib
import json
from pathlib import Path

import torch

WEIGHTS = Path(__file__).resolve().parents[1] / "weights"
CHECK_IMAGES = 64
CHECK_KEYS = ("recon_psnr", "normal_mean", "albedo_si_mse", "sh_error")


def manifest(folder: Path = WEIGHTS) -> dict:
    path = Path(folder) / "manifest.json"
    return json.loads(path.read_text()) if path.exists() else {}


def shipped_names(folder: Path = WEIGHTS) -> list[str]:
    return sorted(manifest(folder))


def shipped_path(name: str, folder: Path = WEIGHTS) -> Path:
    """The checkpoint file of shipped model ``name``; an error listing the shipped names if there is none."""
    entry = manifest(folder).get(name)
    if entry is None:
        raise FileNotFoundError(
            f"{name!r} is neither a run folder, a checkpoint file nor a shipped model; "
            f"shipped models: {', '.join(shipped_names(folder)) or 'none'}"
        )
    return Path(folder) / entry["file"]


def load_weights(model: torch.nn.Module, state: dict, source) -> None:
    """``model.load_state_dict(state)`` that names what does not match instead of a raw traceback."""
    own = model.state_dict()
    missing = sorted(set(own) - set(state))
    unexpected = sorted(set(state) - set(own))
    shapes = [
        f"{k}: checkpoint {tuple(state[k].shape)} vs model {tuple(v.shape)}"
        for k, v in own.items()
        if k in state and tuple(state[k].shape) != tuple(v.shape)
    ]
    if missing or unexpected or shapes:
        parts = (
            [f"missing in the checkpoint: {', '.join(missing[:6])}{' ...' if len(missing) > 6 else ''}"]
            if missing
            else []
        )
        parts += (
            [f"not in the model: {', '.join(unexpected[:6])}{' ...' if len(unexpected) > 6 else ''}"]
            if unexpected
            else []
        )
        parts += [f"shape mismatch: {'; '.join(shapes[:4])}"] if shapes else []
        raise ValueError(
            f"the checkpoint {source} does not match the model its config builds with this code "
            f"({'; '.join(parts)}); it was written by another version of disent"
        )
    model.load_state_dict(state)


def check_metrics(model, cfg, n: int = CHECK_IMAGES) -> dict:
    """The ``CHECK_KEYS`` metrics of ``model`` on the first ``n`` test images of its data set."""
    from disent.data import make_dataset
    from disent.eval.evaluate import evaluate_model

    test = make_dataset(cfg.data, "test", cfg.data.get("test_size"))
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
