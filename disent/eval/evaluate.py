"""The evaluation of a model: every test metric on SynthFaces' truth beside the trivial baselines
(``evaluate_model``, the ``eval.json`` a run writes), the run's summary printed, and ``python -m disent.eval.evaluate
RUN`` to score finished runs again.  The per-output metrics are :mod:`disent.eval.scoring`; nothing here trains.
"""

from __future__ import annotations

from pathlib import Path

import torch

from disent.data import make_dataset
from disent.eval.scoring import completed_light_metrics, metrics_from_outputs, model_outputs
from disent.eval.trivial import dataset_means, trivial_metrics
from disent.lighting.targets import target_light_of


def evaluate_model(
    model, dataset, limit: int = 256, batch_size: int = 64, trivial: dict | None = None, light_target=None
) -> dict:
    """All test metrics of ``model`` on the first ``limit`` items of ``dataset`` plus ``infer_images_per_s``;
    with ``trivial`` (:func:`disent.eval.trivial.dataset_means`) the ``trivial_*`` baselines on the same images;
    with ``light_target`` (``batch -> [B, C, 9]``, :func:`disent.lighting.targets.target_light_of`) the light it
    was taught, scored as its own (``target_*``)."""
    out, gt, ips = model_outputs(model, dataset, limit, batch_size)
    if light_target is not None and "sh" in out:
        gt["sh_target"] = light_target(gt).float()
    m = {**metrics_from_outputs(out, gt), "infer_images_per_s": ips, "n_eval": len(gt["image"])}
    if trivial is None:
        return m
    return {
        **m,
        **trivial_metrics(trivial, gt),
        **(completed_light_metrics(out, gt, trivial["sh"]) if "sh" in out else {}),
    }


def trivial_baselines(train) -> dict | None:
    """The constant estimates of :mod:`disent.eval.trivial` from the training set ``train`` (None without
    ground truth, e.g. real photos)."""
    return dataset_means(train) if "normal" in train[0] else None


def evaluate(model, cfg, n: int, trivial: dict | None) -> dict:
    """Test metrics on the first ``n`` test images (disent.eval.evaluate), on the CPU, with the trivial
    baselines ``trivial`` (:func:`trivial_baselines`) and the setting's E_recon-L target (:func:`target_light_of`)
    scored on the same images where the data has ground truth."""
    from disent.eval.metrics import reconstruction_metrics

    test = make_dataset(cfg.data, "test", cfg.data.get("test_size"), device="cpu")
    model = model.to("cpu")
    if "normal" in test[0]:
        return evaluate_model(model, test, limit=n, trivial=trivial, light_target=target_light_of(cfg.loss))
    out, gt, ips = model_outputs(model, test, limit=n)  # real photos: no intrinsic ground truth
    rec = reconstruction_metrics(out["recon"].clamp(0, 1), gt["image"])
    return {**{f"recon_{k}": v for k, v in rec.items()}, "infer_images_per_s": ips, "n_eval": len(gt["image"])}


LAYERS = (  # (label, network key, trivial key, pseudo-GT key, unit): lower is better but for HIGHER_BETTER
    ("normals, angular error", "normal_mean", "trivial_normal_mean", "pseudo_normal_mean", "deg"),
    ("albedo, scale-inv. MSE", "albedo_si_mse", "trivial_albedo_si_mse", None, ""),
    ("  its coarse part", "albedo_coarse_si_mse", "trivial_albedo_coarse_si_mse", None, ""),  # 2-px blur of the error
    ("  its detail", "albedo_fine_si_mse", "trivial_albedo_fine_si_mse", None, ""),  # what the blur leaves
    ("albedo, detailed (I / S)", "albedo_detailed_si_mse", "trivial_albedo_si_mse", None, ""),  # Sec. 5.3
    ("albedo, one scale", "albedo_global_si_mse", "trivial_albedo_global_si_mse", None, ""),
    ("albedo, with hair+neck", "albedo_face_si_mse", "trivial_albedo_face_si_mse", None, ""),
    ("albedo, one scale for RGB", "albedo_colour_si_mse", "trivial_albedo_colour_si_mse", None, ""),  # skin colour
    ("shading, scale-inv. MSE", "shading_si_mse", "trivial_shading_si_mse", None, ""),
    ("  one scale for RGB", "shading_colour_si_mse", "trivial_shading_colour_si_mse", None, ""),  # light's colour
    ("light, SH error", "sh_error", "trivial_sh_error", "pseudo_sh_error", ""),
    ("  shown by the face", "sh_error_shown", "trivial_sh_error_shown", "pseudo_sh_error_shown", ""),  # scale from
    ("  hidden from it", "sh_error_hidden", "trivial_sh_error_hidden", "pseudo_sh_error_hidden", ""),  # shading
    ("  completed by the mean", "sh_error_completed", "trivial_sh_error", "pseudo_sh_error_completed", ""),
    ("light, on the face", "light_shading_si_mse", "trivial_light_shading_si_mse", "pseudo_light_shading_si_mse", ""),
    ("matte, IoU with the face", "matte_iou", "trivial_matte_iou", "pseudo_matte_iou", ""),  # Sec. 3.3
)
HIGHER_BETTER = {"matte_iou"}


def learned_layers(m: dict) -> dict:
    """``{network key: True/False}``: whether each layer beats its trivial (dataset-mean) baseline."""
    beats = lambda net, triv: m[net] > m[triv] if net in HIGHER_BETTER else m[net] < m[triv]
    return {net: beats(net, triv) for _, net, triv, _, _ in LAYERS if net in m and triv in m}


def print_eval(m: dict, run_dir) -> None:
    print(f"\ntest metrics ({m['n_eval']} images) -> {Path(run_dir) / 'eval.json'}")
    print(
        f"  reconstruction  mse {m['recon_mse']:.5f}  psnr {m['recon_psnr']:.2f} dB  ssim {m['recon_ssim']:.3f}"
        + (f"   face psnr {m['recon_face_psnr']:.2f} dB" if "recon_face_psnr" in m else "")
    )
    learned = learned_layers(m)
    if any(net in m for _, net, _, _, _ in LAYERS):
        print(
            "  intrinsic layers on the face inside the pseudo mask (the model's own foreground; the last albedo line:"
            " the whole face, whose hair and neck the model leaves to its background layer)"
        )
    for label, net, triv, pseudo, unit in LAYERS:
        if net in m:
            line = f"  {label:<24} network {m[net]:.4g}{unit}"
            line += f"   trivial {m[triv]:.4g}{unit}" if triv in m else ""
            line += f"   pseudo-GT {m[pseudo]:.4g}{unit}" if pseudo and pseudo in m else ""
            if net == "sh_error" and "trivial_lhat_sh_error" in m:
                line += f"   mean L-hat {m['trivial_lhat_sh_error']:.4g}"
            if f"target_{net}" in m:  # the light E_recon-L taught it, where that is not L-hat (target_light_of)
                line += f"   its target {m[f'target_{net}']:.4g}"
            if net in learned:
                line += "   learned" if learned[net] else "   NOT learned (no better than the dataset mean)"
            if f"template_{net}" in m:  # the mean texture placed by the true uv: the face's placement, no identity
                template = m[f"template_{net}"]
                line += f"; placed mean texture {template:.4g}" + ("" if m[net] < template else " (NOT beaten)")
            print(line)
    if "normal_spread" in m:
        from disent.eval.metrics import frame_map, normals_failure

        failure = {
            "flat": "   FLAT: the normals collapsed",
            "frame": "   FRAME: the shape learned in a rotated or mirrored frame",
            "astray": "   ASTRAY: farther than the dataset mean",
        }.get(normals_failure(m), "")
        print(
            f"  normals' spread about each face's mean  network {m['normal_spread']:.1f}deg   "
            f"truth {m['true_normal_spread']:.1f}deg{failure}"
        )
        if "normal_aligned_mean" in m:
            print(
                f"  normals after the best rotation or mirror of the frame  {m['normal_aligned_mean']:.2f}deg   "
                f"({frame_map(m)})"
            )
    if "sh_error_coefficients" in m and "trivial_sh_error_coefficients" in m:
        names = ("DC", "y", "z", "x", "xy", "yz", "3z2-1", "xz", "x2-y2")
        print("  light error by SH coefficient " + " ".join(f"{n:>6}" for n in names))
        for who, key in (("network", "sh_error_coefficients"), ("dataset mean", "trivial_sh_error_coefficients")):
            print(f"  {who:>30} " + " ".join(f"{v:6.3f}" for v in m[key]))


def score(source) -> dict:
    """The test metrics a finished run writes to ``eval.json`` (with the trivial baselines), for the model of
    ``source``: a run folder, a checkpoint or a shipped name (:func:`disent.models.load_run`)."""
    from disent.models import load_run

    model, cfg = load_run(source)
    trivial = trivial_baselines(make_dataset(cfg.data, "train", cfg.data.get("train_size"), device="cpu"))
    return evaluate(model.eval(), cfg, cfg.train.eval_size, trivial)


def rescore(run_dir) -> dict:
    """Score a finished run's final checkpoint again with this version's metrics: ``eval.json`` is rewritten
    (atomically), keeping its training bookkeeping (``steps``, ``stopped_by``, ``train_seconds``) and its measured
    inference speed (a rescore may run on a busier machine)."""
    import json
    from pathlib import Path

    from disent.storage import atomic_write

    run_dir = Path(run_dir)
    old = json.loads((run_dir / "eval.json").read_text()) if (run_dir / "eval.json").exists() else {}
    metrics = {
        **score(run_dir),
        **{k: old[k] for k in ("steps", "stopped_by", "train_seconds", "infer_images_per_s") if k in old},
    }
    atomic_write(run_dir / "eval.json", lambda f: f.write(json.dumps(metrics, indent=2).encode()))
    return metrics


def main(argv=None):
    import argparse

    p = argparse.ArgumentParser(
        prog="python -m disent.eval.evaluate",
        description="Score finished runs again with this version's metrics (eval.json).",
    )
    p.add_argument("runs", nargs="+", help="run folders with checkpoints/last.pt")
    a = p.parse_args(argv)
    torch.set_num_threads(1)
    for run in a.runs:
        print_eval(rescore(run), run)


if __name__ == "__main__":
    main()
