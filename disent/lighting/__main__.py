"""``python -m disent.lighting``: the lighting posterior of one image or a split (conf/lighting.yaml)."""

from __future__ import annotations

import json
import logging
from pathlib import Path

import hydra
import torch
from omegaconf import DictConfig

import disent.runs  # noqa: F401  (registers ${pid:}, used by the default run folder in conf/lighting.yaml)
from disent.lighting.experiments import figures_for, order_report, run_all
from disent.lighting.geometry import GEOMETRY, noisy, save_json, scene_geometry
from disent.lighting.order import select_order
from disent.lighting.order_study import chosen_noise_model, order_data
from disent.lighting.posterior import prepare, sample_posterior
from disent.lighting.sources import lhat_sources
from disent.runtime import single_core
from disent.storage import tool_folder

log = logging.getLogger(__name__)
TASKS = ("posterior", "report", "order", "lhat")


def load_photo(path: str, resolution: int, cache_dir=None) -> dict:
    """A photo with its pseudo ground truth (:mod:`disent.data.photos.pseudo_gt`)."""
    from disent.data.photos.pseudo_gt import PseudoGTSettings, crop_pixels, load_cached
    from disent.data.photos.pseudo_gt import prepare as pseudo_gt

    (rec,), _ = pseudo_gt([path], PseudoGTSettings(resolution=resolution), cache_dir, progress=False)
    if not rec.used:
        raise ValueError(f"no usable face in {path}: {rec.reason} {rec.detail}")
    arrays = load_cached(rec)
    item = {k: torch.as_tensor(v).float() for k, v in arrays.items() if v.dtype.kind in "fiub"}
    item["image"] = torch.from_numpy(crop_pixels(arrays["image"]))  # stored as HxWx3 sRGB uint8
    return item


def items(cfg: DictConfig):
    """``(name, item, ds, index)`` of each image the run fits: a photo (``ds``, ``index`` None), or SynthFaces
    scenes, whose parameters the geometries that render the coarse fit again need (``place``, ``made_true``)."""
    if cfg.image:
        yield Path(cfg.image).stem, load_photo(cfg.image, cfg.data.resolution, cfg.get("cache_dir")), None, None
        return
    from disent.data import SynthFaces

    ds = SynthFaces(cfg.split, cfg.data.resolution, cfg.data.seed, effects=cfg.data.effects)
    for i in range(cfg.n_images) if cfg.n_images > 1 else [cfg.index]:
        yield f"{cfg.split}_{i:05d}", ds[i], ds, i


def posterior_of(cfg: DictConfig, name: str, item: dict, ds=None, index: int | None = None) -> dict:
    normals = "normal_pseudo" if cfg.image else cfg.normals
    mask = item["mask_pseudo"] if normals == "normal_pseudo" else item["matte"]
    albedo = item["albedo"] if cfg.known_albedo and "albedo" in item else None
    noise = cfg.noise if cfg.noise is not None else (0.0 if cfg.image else 0.01)
    data = prepare(noisy(item["image"], noise, cfg.seed), item[normals], mask, albedo, gray=cfg.gray)
    post = sample_posterior(
        data, order=cfg.order, likelihood=cfg.likelihood, nu=cfg.nu, seed=cfg.seed, max_steps=cfg.max_steps
    )
    result = {"name": name, "normals": normals, "known_albedo": albedo is not None} | post.summary()
    # the order choice: without a known albedo, the texture model on the geometry the order study chose
    geometry = cfg.order_geometry if normals == "normal_pseudo" else "normal"
    choice_data, texture = data, None
    if albedo is None and cfg.texture_components > 0 and not cfg.gray:
        item = scene_geometry(ds, index, item, geometry, noise, cfg.seed)  # a network's maps, a coarse fit redrawn
        if GEOMETRY[geometry].uv in item:
            choice_data, texture = order_data(item, noise, cfg.seed, "texture", geometry, cfg.texture_components)
    geometry = geometry if texture is not None else normals
    kind = "texture" if texture is not None else "known" if albedo is not None else "constant"
    study = Path(hydra.utils.to_absolute_path(cfg.order_study))
    if cfg.order_noise == "auto" and not (study / "order.json").exists():
        log.warning("no order study in %s: the order choice assumes i.i.d. noise", study)
    model, noise_kwargs = chosen_noise_model(kind, geometry, study, cfg.order_noise)  # the study's, or the one set
    choice = select_order(choice_data, texture=texture, **noise_kwargs)
    result["order_choice"] = {k: v for k, v in choice.items() if k != "criterion"} | {"noise_model": model}
    result["order_choice"] |= noise_kwargs
    result["order_choice"]["geometry"] = geometry
    result["order_choice"]["texture_components"] = 0 if texture is None else len(texture[1])
    if "sh" in item:
        truth = item["sh"].double().numpy()
        result["true_sh"] = truth.tolist()
        if albedo is not None and not cfg.gray:
            for level in (0.68, 0.95):
                lo, hi = post.interval(level)
                result[f"true_inside{int(level * 100)}"] = float(((truth >= lo) & (truth <= hi)).mean())
    return result, post, data


@hydra.main(version_base="1.3", config_path="../../conf", config_name="lighting")
def main(cfg: DictConfig) -> None:
    with single_core():
        run(cfg)


def run(cfg: DictConfig) -> None:
    if cfg.task not in TASKS:
        raise ValueError(f"task must be one of {', '.join(TASKS)}, got {cfg.task!r}")
    out = tool_folder("lighting", hydra.utils.to_absolute_path(cfg.out))
    if cfg.task == "report":
        run_all(out, cfg.split, cfg.data.resolution, cfg.data.seed, geometry=cfg.order_geometry)
    if cfg.task == "order":
        keep = hydra.utils.to_absolute_path(cfg.order_keep) if cfg.order_keep else None
        only = list(cfg.order_rows) if cfg.order_rows else None
        splits = list(cfg.order_splits) if cfg.order_splits else None
        order_report(
            out,
            cfg.split,
            cfg.data.resolution,
            cfg.data.seed,
            only=only,
            keep=keep,
            splits=splits,
            n_per_order=cfg.order_n,
            geometry=cfg.order_geometry,
        )
    if cfg.task == "lhat":
        from disent.data import SynthFaces

        r, s = cfg.data.resolution, cfg.data.seed
        save_json("lhat_sources", lhat_sources(SynthFaces(cfg.split, r, s), SynthFaces("train", r, s)), out)
    if cfg.task != "posterior":
        log.info("wrote %s; publish it with: python -m disent.report --publish %s", out, out)
        return
    results = []
    for k, (name, item, ds, index) in enumerate(items(cfg)):
        result, post, data = posterior_of(cfg, name, item, ds, index)
        if cfg.figures and k < 4:
            result["figures"] = [
                str(p) for p in figures_for(post, item, data, out / name, "normal_pseudo" if cfg.image else cfg.normals)
            ]
        d = result["diagnostics"]
        log.info(
            "%s: %d pixels, %d steps, tau %.1f, acceptance %.2f, ESS %.0f, converged %s, %.2f s; order choice %s",
            name,
            d["n_pixels"],
            d["n_steps"],
            d["tau_max"],
            d["acceptance_fraction"],
            d["ess_min"],
            d["converged"],
            d["seconds"],
            result["order_choice"]["choice"],
        )
        results.append(result)
    path = out / "posterior.json"
    path.write_text(json.dumps(results if len(results) > 1 else results[0], indent=2))
    log.info("wrote %s", path)


if __name__ == "__main__":
    main()
