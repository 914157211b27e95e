"""The lighting model order study: the order each scene's light is chosen at (evidence, BIC) on each
albedo, geometry and noise model, its failures, and the residual process's fit."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import torch

from disent.lighting.geometry import ALBEDO, GEOMETRY, item_data, load_tables, save_json, scene_geometry
from disent.lighting.order import choose, fitted, select_order
from disent.lighting.posterior import N_COEFFS
from disent.render import C4, sh_basis
from disent.storage import machine_info


# ----------------------------------------------------------------------------- order choice
def light_of_order(sh: torch.Tensor, order: int) -> torch.Tensor:
    """The scene's light cut to SH band ``order``; ambient raised so the front-facing normals
    (n_z >= -0.3, as the generator checks) stay at least 4 % of the peak shading."""
    sh = sh.double().clone()
    sh[:, N_COEFFS[order] :] = 0
    g = torch.Generator().manual_seed(0)
    n = torch.nn.functional.normalize(torch.randn(4096, 3, generator=g, dtype=torch.float64), dim=1)
    B = sh_basis(n[n[:, 2] >= -0.3].T.contiguous(), 0)  # [9, M]
    s = sh @ B
    sh[:, 0] += (0.04 * s.amax(1) - s.amin(1)).clamp_min(0) / C4
    return sh.float()


def order_data(
    item: dict, noise: float, seed: int, albedo: str = "constant", normals: str = "normal", n_components: int = 20
):
    """``(LightingData, texture or None)`` of one item for the order choice.

    ``albedo``: ``known`` (the true map), ``constant`` (L-hat's assumption) or ``texture``
    (:mod:`disent.lighting.texture`, mapped through the geometry's UV); ``normals``:
    ``normal`` (true normals, matte, uv) or ``normal_pseudo`` (the coarse fit's, with its mask and uv).
    """
    from disent.lighting.texture import texture_for

    if albedo not in ALBEDO or normals not in GEOMETRY:
        raise ValueError(f"albedo must be one of {ALBEDO} and normals one of {tuple(GEOMETRY)}")
    data = item_data(item, noise, seed, known_albedo=albedo == "known", normals=normals, texture=albedo == "texture")
    if albedo != "texture":
        return data, None
    return data, texture_for(data, uv_of(item, data, normals, n_components), n_components)


def uv_of(item: dict, data, normals: str, n_components: int = 20) -> torch.Tensor:
    """The uv through which the texture model reaches ``data``'s pixels on geometry ``normals``: the item's,
    registered to the image first where the geometry says so (:func:`disent.lighting.texture.register`)."""
    from disent.lighting.texture import register, registration_prior, texture_model

    geometry, uv = GEOMETRY[normals], item[GEOMETRY[normals].uv]
    if not geometry.register:
        return uv
    # the prior of the affine corrections: of the pseudo uv, or of the network's own uv where the row reads that
    own = geometry.network if geometry.uv == "uv_net" else ""
    prior = registration_prior(uv.shape[-1], network=own)
    return register(data, uv, texture_model(uv.shape[-1], n_components), prior=prior)


def order_scene(ds, index: int, order: int, noise: float, albedo: str, normals: str, n_components: int = 20):
    """``(sh, item, data, texture)`` of the order study's scene: item ``index`` of ``ds`` under its own light cut to
    ``order``, noisy (seed ``1000 order + index``), on the geometry ``normals`` (:func:`scene_geometry`) with the
    albedo model ``albedo`` (:func:`order_data`)."""
    sh = light_of_order(ds[index]["sh"], order)
    seed = 1000 * order + index
    item = scene_geometry(ds, index, ds.sample(index, sh=sh), normals, noise, seed)
    return (sh, item, *order_data(item, noise, seed, albedo, normals, n_components))


def order_confusion(
    ds,
    n_per_order: int = 30,
    noise: float = 0.02,
    albedo: str = "constant",
    normals: str = "normal",
    n_components: int = 20,
    noise_model: dict | None = None,
) -> dict:
    """Confusion matrices (true order x chosen order) for the evidence and for BIC.

    Item ``i`` of ``ds`` is relit with its own light cut to each order (:func:`light_of_order`);
    ``noise_model``: keyword arguments of :func:`~disent.lighting.order.select_order` (``normal_sigma``,
    ``residual``); default i.i.d. noise.  ``band2_share``: the medians of :func:`~disent.lighting.order.band2_share`
    of the largest candidate's light by true order, and of the true order-2 lights: where the fit puts as much in
    band 2 for an order-1 scene as a true order-2 light has, no criterion built on the fit can tell them apart.
    """
    from disent.lighting.order import band2_share

    conf = {"evidence": np.zeros((3, 3), int), "bic": np.zeros((3, 3), int)}
    colour = {"evidence": {}, "bic": {}}
    band2 = {"fitted": [[], [], []], "true": []}  # the largest candidate's band-2 share by true order; the truth's
    scenes = {k: [] for k in ("index", "true_order", "evidence", "bic", "yaw", "pixels")}  # each scene's outcome
    yaw = ds.params(list(range(n_per_order)))["pose"][:, 0].tolist()  # each face's, degrees
    for order in range(3):
        for i in range(n_per_order):
            sh, item, data, texture = order_scene(ds, i, order, noise, albedo, normals, n_components)
            scores = select_order(data, texture=texture, **(noise_model or {}))["scores"]
            band2["fitted"][order].append(band2_share(list(scores.values())[-1]["light"]))
            if order == 2:
                band2["true"].append(band2_share(sh))
            for crit in conf:
                r = choose(scores, crit)
                conf[crit][order, r["order"]] += 1
                colour[crit][r["choice"]] = colour[crit].get(r["choice"], 0) + 1
                scenes[crit].append(r["order"])
            scenes["index"].append(i)
            scenes["true_order"].append(order)
            scenes["yaw"].append(round(yaw[i], 2))
            scenes["pixels"].append(len(data.y))
    return {
        crit: {
            "confusion": m.tolist(),
            "accuracy": float(np.trace(m) / m.sum()),
            "per_order_recall": (np.diag(m) / m.sum(1)).tolist(),
            "chosen_models": colour[crit],
        }
        for crit, m in conf.items()
    } | {
        "band2_share": {  # medians: what the largest candidate fits into band 2, by true order, and the truth's
            "fitted_by_true_order": [float(np.median(v)) for v in band2["fitted"]],
            "true_order2": float(np.median(band2["true"])) if band2["true"] else None,
        },
        "scenes": scenes,  # per scene: its index, true order, the order each criterion chose, yaw (deg), pixels fitted
        "settings": {
            "split": ds.split,
            "seed": ds.seed,
            "machine": machine_info(),  # the placed geometry's Powell path depends on the libraries' floating point
            "n_per_order": n_per_order,
            "noise": noise,
            "albedo": albedo,
            "normals": normals,
            "n_components": n_components if albedo == "texture" else 0,
            "noise_model": noise_model or {},
        },
    }


# The geometry-error noise model (disent.lighting.order) for pseudo geometry.  normal_sigma: the pseudo-GT's
# measured mean angular error on SynthFaces, 11.5 deg = 0.20 rad, as the per-axis std of an isotropic tangent
# Gaussian (mean |delta n| = sigma sqrt(pi/2)); set from that measurement, not fitted to the order choice.
GEOMETRY_NOISE = {"normal_sigma": 0.16}


def geometry_noise(normals: str) -> dict:
    """The geometry-error noise model of geometry ``normals``: :data:`GEOMETRY_NOISE` for the pseudo-GT's maps; for
    a network row, the same reading of the shipped model's own measured mean normal error (its test metrics in
    ``disent/weights/manifest.json``)."""
    network = GEOMETRY[normals].network
    if not network:
        return GEOMETRY_NOISE
    from disent.models.shipped import manifest

    mean = np.radians(manifest()[network]["metrics"]["normal_mean"])
    return {"normal_sigma": float(mean / np.sqrt(np.pi / 2))}


# (albedo, normals[, noise model]); "residual_process": rho, ell by fit_residual_process on train scenes, on the
# row's own geometry; "geometry_noise+residual_process": both, rho and ell fitted beside the geometry noise
ORDER_ROWS = load_tables()["order_rows"]  # (albedo, geometry[, noise model]): disent/lighting/tables.yaml
ORDER_TARGET = 0.85  # share of scenes whose lighting order is chosen right on pseudo geometry
NOISE_MODELS = ("geometry_noise", "residual_process", "geometry_noise+residual_process", "residual_process+student_t")
# "+student_t": the whitened noise Student-t of STUDENT_T_NU degrees of freedom (disent.lighting.order.score); nu
# chosen on val among 4 and 10 (120 scenes of the normal_pseudo_placed_registered row: 0.91 and 0.93 against 0.87;
# on all 300 of its val scenes 0.900 and 0.903)
STUDENT_T_NU = 10.0
RESIDUAL_GRID = {"rho": (1.0, 3.0, 10.0, 30.0, 100.0, 300.0, 1000.0), "ell": (0.5, 1.0, 2.0, 4.0)}


def true_light_residuals(
    ds, n_scenes: int, noise: float = 0.02, normals: str = "normal_pseudo", normal_sigma: float = 0.0
) -> list:
    """``(data, residual [P, C], extra)`` of scenes ``0..n-1`` of ``ds`` (lights cut to order ``i % 3``) on the
    pseudo geometry ``normals`` (a key of :data:`GEOMETRY`): the image less the texture model's albedo (ridge fit
    under its PCA prior, and a gain per channel) times the scene's true light through the pseudo normals, the misfit
    the right lighting model leaves; ``extra [P, C]``: the variance the geometry noise ``normal_sigma`` adds to each
    value at that light and albedo (:func:`~disent.lighting.order.geometry_variance`; None where 0)."""
    from dataclasses import replace

    from disent.lighting.order import geometry_variance, texture_albedo, texture_coefficients
    from disent.lighting.texture import texture_for

    out = []
    for i in range(n_scenes):
        sh = light_of_order(ds[i]["sh"], i % 3)
        item = scene_geometry(ds, i, ds.sample(i, sh=sh), normals, noise, 7000 + i)
        data = item_data(item, noise, 7000 + i, known_albedo=False, normals=normals, texture=True)
        tex, variance = texture_for(data, uv_of(item, data, normals))
        shading = data.basis @ sh.double().numpy().T  # [P, C]
        beta, _ = texture_coefficients(tex, variance, shading, data.y, np.full(data.y.shape, noise**2))
        albedo = texture_albedo(tex, beta)
        gain = (albedo * shading * data.y).sum(0) / ((albedo * shading) ** 2).sum(0)
        data = replace(data, albedo=gain * albedo)
        extra = geometry_variance(data, sh.double().numpy(), normal_sigma) if normal_sigma > 0 else None
        out.append((data, data.y - data.albedo * shading, extra))
    return out


def fit_residual_process(
    ds, n_scenes: int = 18, grid: dict = RESIDUAL_GRID, normals: str = "normal_pseudo", normal_sigma: float = 0.0
) -> dict:
    """``rho, ell`` of the order choice's residual process (:class:`disent.lighting.order.Whitener`) by maximum
    likelihood (sigma profiled) over :func:`true_light_residuals` of ``ds`` (the train split) on the geometry
    ``normals``, with the geometry noise ``normal_sigma`` beside it (0: the residual process alone), on a grid;
    returns ``{"rho", "ell", "log_likelihood": {"rho,ell": value}}``."""
    fit = max_likelihood_residual(true_light_residuals(ds, n_scenes, normals=normals, normal_sigma=normal_sigma), grid)
    return fit | {"n_scenes": n_scenes, "split": ds.split, "normals": normals, "normal_sigma": normal_sigma}


def max_likelihood_residual(residuals: list, grid: dict = RESIDUAL_GRID) -> dict:
    """``{"rho", "ell", "log_likelihood"}``: the grid point of the largest summed log-likelihood of the
    ``(data, residual [P, C], extra)`` triples under the residual process (beside the geometry's variance ``extra
    [P, C]``, or None), sigma at its maximum per triple."""
    from disent.lighting.order import Whitener, noise_variance, unit

    table = {}
    for rho in grid["rho"]:
        for ell in grid["ell"]:
            total = 0.0
            for data, r, extra in residuals:
                whiten = Whitener(data, rho, ell)
                v = noise_variance(r, extra, whiten)
                u = unit(r, v, whiten)
                total += -0.5 * (
                    r.size * np.log(2 * np.pi) + (u**2).sum() + np.log(v).sum() + r.shape[1] * whiten.log_det
                )
            table[f"{rho:g},{ell:g}"] = total
    rho, ell = map(float, max(table, key=table.get).split(","))
    return {"rho": rho, "ell": ell, "log_likelihood": table}


def noise_parts(model: str) -> tuple[bool, bool, bool]:
    """``(geometry noise, residual process, Student-t)``: whether the noise model ``model`` (``iid`` or one of
    :data:`NOISE_MODELS`) has each part."""
    if model not in ("iid", *NOISE_MODELS):
        raise ValueError(f"unknown noise model {model!r}; choose from iid, {', '.join(NOISE_MODELS)}")
    parts = model.split("+")
    return "geometry_noise" in parts, "residual_process" in parts, "student_t" in parts


def fit_key(normals: str, model: str) -> str:
    """The key of a row's residual fit in ``residual_process.json``: its geometry, and ``+geometry_noise`` where the
    fit had the geometry noise beside it."""
    return normals + ("+geometry_noise" if noise_parts(model)[0] else "")


def read_study(folder: Path | None, name: str = "order") -> dict:
    """``{name: rows, "residual_process": fits}`` of the order study in ``folder`` (``{}`` for a file it lacks, or
    for no folder)."""
    files = (name, "residual_process")
    return {
        f: json.loads((Path(folder) / f"{f}.json").read_text())
        if folder and (Path(folder) / f"{f}.json").exists()
        else {}
        for f in files
    }


def noise_model(normals: str, model: str, fits: dict) -> dict:
    """:func:`~disent.lighting.order.select_order`'s keyword arguments of the noise model ``model`` (``iid`` or one of
    :data:`NOISE_MODELS`) on the geometry ``normals``; ``fits``: the residual fits (``residual_process.json``)."""
    geometry, residual, student_t = noise_parts(model)
    kwargs = (geometry_noise(normals) if geometry else {}) | ({"nu": STUDENT_T_NU} if student_t else {})
    if residual:
        if fit_key(normals, model) not in fits:
            raise ValueError(f"no residual fit {fit_key(normals, model)!r} in the study; its fits: {', '.join(fits)}")
        fit = fits[fit_key(normals, model)]
        kwargs = kwargs | {"residual": (fit["rho"], fit["ell"])}
    return kwargs


def best_on_val(order: dict, accept) -> str | None:
    """The name (after ``val/``) of the order study's val row of best evidence accuracy among those whose name
    ``accept(name)`` takes; None where there is none."""
    rows = [k[4:] for k in order if k.startswith("val/") and accept(k[4:])]
    return max(rows, key=lambda k: order[f"val/{k}"]["evidence"]["accuracy"], default=None)


def chosen_noise_model(albedo: str, normals: str, study: Path, model: str = "auto") -> tuple[str, dict]:
    """``(model, select_order keyword arguments)``: the noise model ``model`` on the geometry ``normals``, its residual
    fit read from the order study in folder ``study``; ``auto``: the noise model of the study's ``albedo/normals`` row
    best on val (``iid`` where the study has no such row)."""
    study = read_study(study)
    order, fits = study["order"], study["residual_process"]
    if model == "auto":
        row = f"{albedo}/{normals}"
        best = best_on_val(order, lambda k: k == row or k.startswith(f"{row}+")) or row
        model = best[len(row) + 1 :] or "iid"
    return model, noise_model(normals, model, fits)


def row_key(row: tuple) -> str:
    """``albedo/normals[+noise model]``: an order-study row's name (its key in ``order.json`` after ``split/``)."""
    albedo, normals, *model = row
    return f"{albedo}/{normals}" + (f"+{model[0]}" if model else "")


def order_study(
    out: Path,
    splits=("val", "test"),
    rows=ORDER_ROWS,
    n_per_order: int = 20,
    noise: float = 0.02,
    resolution: int = 64,
    seed: int = 0,
    name: str = "order",
    n_train_scenes: int = 18,
    only=None,
    keep: Path | None = None,
) -> dict:
    """The order-choice confusion matrices of every ``(albedo, normals[, noise model])`` row on each split
    (the residual process fitted first on ``n_train_scenes`` train scenes, per geometry of a row that uses it,
    ``out/residual_process.json``; a fit the earlier study in ``keep`` holds is kept, so that rows on one geometry,
    compared on the same scenes, differ only in what their names say);
    written to ``out/<name>.json`` (the method and its constants are chosen on
    ``val``; ``test`` only reports).

    ``only``: names of the rows (:func:`row_key`) to compute; every other row, and its residual fit, is copied from
    the earlier study in folder ``keep`` (``<name>.json``, ``residual_process.json``) where it has one, so that a
    new row joins a published study without running the others again; so is every row of a split not in ``splits``
    (a row read again on test alone, with more scenes, keeps its val entry).
    """
    from disent.data import SynthFaces

    names = [row_key(row) for row in rows]
    unknown = sorted(set(only or ()) - set(names))
    if unknown:
        raise ValueError(f"unknown order-study rows {unknown}; rows: {', '.join(names)}")
    todo = [row for row in rows if only is None or row_key(row) in only]
    earlier = read_study(keep, name)
    result, fits = {}, dict(earlier["residual_process"])
    train = SynthFaces("train", resolution, seed)
    for normals, model in dict.fromkeys((row[1], row[2]) for row in todo if row[2:] and noise_parts(row[2])[1]):
        if fit_key(normals, model) in fits:  # kept: the rows on one geometry read with one fit
            continue
        geometry = geometry_noise(normals)["normal_sigma"] if noise_parts(model)[0] else 0.0
        fits[fit_key(normals, model)] = fit_residual_process(
            train, n_train_scenes, normals=normals, normal_sigma=geometry
        )
        save_json("residual_process", fits, out)

    # val first, then the splits computed here, then those only kept, each split's rows in the order of ``rows``
    for split in dict.fromkeys(("val", *splits, *(k.split("/", 1)[0] for k in earlier[name]))):
        ds = SynthFaces(split, resolution, seed) if split in splits else None
        for row in rows:
            key = f"{split}/{row_key(row)}"
            if row not in todo or ds is None:
                if key in earlier[name]:
                    result[key] = earlier[name][key]
                continue
            albedo, normals, *model = row
            result[key] = order_confusion(
                ds,
                n_per_order,
                noise,
                albedo,
                normals,
                noise_model=noise_model(normals, model[0], fits) if model else None,
            )
            save_json(name, result, out)
    save_json(name, result, out)
    return result


def wilson_interval(share: float, n: int, z: float = 1.96) -> tuple[float, float]:
    """The Wilson score interval of a proportion ``share`` observed over ``n`` trials (95 % at ``z = 1.96``)."""
    centre = (share + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(share * (1 - share) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return centre - half, centre + half


def plot_order_accuracy(study: dict, path: Path, criterion: str = "evidence") -> None:
    """Every row of :func:`order_study` on one axis: its accuracy on val and on test with 95 % intervals (Wilson,
    over the row's scenes), against :data:`ORDER_TARGET`; the confusion matrices themselves are in the JSON."""
    from disent.images import pyplot

    plt = pyplot()

    names = list(dict.fromkeys(key.split("/", 1)[1] for key in study))  # rows in the study's order, val's first
    splits = {"val": ("tab:blue", "none", -0.17), "test": ("tab:orange", "tab:orange", 0.17)}  # colour, fill, shift
    fig, ax = plt.subplots(figsize=(9, 1.2 + 0.24 * len(names)))
    for split, (colour, face, shift) in splits.items():
        rows = [(i, study[f"{split}/{name}"][criterion]) for i, name in enumerate(names) if f"{split}/{name}" in study]
        if not rows:
            continue
        y = np.array([i + shift for i, _ in rows])
        acc = np.array([r["accuracy"] for _, r in rows])
        lo, hi = np.array([wilson_interval(r["accuracy"], int(np.sum(r["confusion"]))) for _, r in rows]).T
        ax.errorbar(
            acc,
            y,
            xerr=np.clip((acc - lo, hi - acc), 0, None),
            fmt="o",
            color=colour,
            mfc=face,
            ms=4,
            lw=1,
            label=split,
        )
    ax.axvline(ORDER_TARGET, color="k", ls="--", lw=1, label=f"target {ORDER_TARGET:.2f}")
    ax.axvline(1 / 3, color="grey", ls=":", lw=1, label="one order for every scene (1/3)")  # the trivial choice
    ax.set_yticks(range(len(names)), [name.replace("+", " + ") for name in names], fontsize=7)
    ax.set_ylim(len(names) - 0.5, -0.5)
    ax.set_xlim(0, 1)
    ax.grid(axis="x", alpha=0.3)
    ax.set_xlabel(f"{criterion} accuracy of the order choice (95 % interval over the row's scenes)")
    ax.legend(fontsize=8, ncol=4, loc="upper center", bbox_to_anchor=(0.5, -0.9 / fig.get_figheight()))
    fig.savefig(path, dpi=110, bbox_inches="tight")  # the row names run left of the figure
    plt.close(fig)


def refit_study_scene(ds, study: dict, row: str, split: str, k: int) -> tuple:
    """``(item, data, scores, truth, chosen, residuals)``: scene ``k`` of the order-study row ``row`` on ``split``
    (``ds``; its scene records), fitted again as the study fitted it: every candidate's scores, the true order's best
    candidate and the chosen one, and those two's residuals ``[P, C]`` at the pixels fitted."""
    entry = study["order"][f"{split}/{row}"]
    records, settings = entry["scenes"], entry["settings"]  # the scene as order_confusion drew it
    albedo, geometry = row.split("/", 1)
    normals, _, model = geometry.partition("+")
    order = records["true_order"][k]
    _, item, data, texture = order_scene(
        ds, records["index"][k], order, settings["noise"], albedo, normals, settings["n_components"] or 20
    )  # n_components 0: no texture model
    result = select_order(data, texture=texture, **noise_model(normals, model or "iid", study["residual_process"]))
    scores, chosen = result["scores"], result["choice"]
    truth = max((n for n in scores if scores[n]["order"] == order), key=lambda n: scores[n]["log_evidence"])
    residuals = {name: data.y - fitted(data, scores[name], texture) for name in (truth, chosen)}
    return item, data, scores, truth, chosen, residuals


def order_failure_regions(ds, study: dict, row: str, split: str = "val", edge: int = 2) -> dict:
    """Where the misfit lies that makes the order choice fail: over every scene of ``split`` that the order-study
    row ``row`` gets wrong, fitted again (:func:`refit_study_scene`), how much the larger of the true order's best
    candidate and the chosen one lowers the squared residual (summed over channels) in each part of the face
    (:func:`~disent.data.synth.face_model.face_regions` at the scene's true uv; the pixels within ``edge`` px of
    the fitted region's border first, as the silhouette), as a share of what it lowers in all, beside the share of
    the fitted pixels each part holds. Returns ``{"row", "split", "kinds": {"TRUE->CHOSEN": {"scenes",
    "pixels_fitted", "reduction_share", "pixel_share"}}}``; a share of reduction above the share of pixels: the
    extra SH terms (chosen or turned down) fit that part more than the face as a whole."""
    from scipy.ndimage import binary_erosion

    from disent.data.synth.face_model import face_regions

    records = study["order"].get(f"{split}/{row}", {}).get("scenes")
    if not records:
        return {}
    kinds: dict = {}
    for k, (true, chosen_order) in enumerate(zip(records["true_order"], records["evidence"])):
        if true == chosen_order:
            continue
        item, data, scores, truth, chosen, residuals = refit_study_scene(ds, study, row, split, k)
        small, large = sorted((truth, chosen), key=lambda n: scores[n]["order"])
        reduction = (residuals[small] ** 2 - residuals[large] ** 2).sum(1)  # [P]
        fitted_pixels = np.zeros(data.shape, bool)
        fitted_pixels.flat[data.index] = True
        inner = binary_erosion(fitted_pixels, iterations=edge)
        parts = {"silhouette": ~inner} | {
            name: region.numpy() & inner for name, region in face_regions(item["uv"].permute(1, 2, 0)).items()
        }
        parts["rest"] = ~np.any(list(parts.values()), axis=0)  # the parts of the face, then the rest of the fit
        kind = kinds.setdefault(f"{true}->{chosen_order}", {"scenes": 0, "reduction": {}, "pixels": {}})
        kind["scenes"] += 1
        for name, part in parts.items():
            at = part.flat[data.index]
            kind["reduction"][name] = kind["reduction"].get(name, 0.0) + float(reduction[at].sum())
            kind["pixels"][name] = kind["pixels"].get(name, 0) + int(at.sum())
    for kind in kinds.values():
        total, n = sum(kind["reduction"].values()), sum(kind["pixels"].values())
        kind["pixels_fitted"] = n
        kind["reduction_share"] = {name: r / total for name, r in kind.pop("reduction").items()}
        kind["pixel_share"] = {name: p / n for name, p in kind.pop("pixels").items()}
    return {"row": row, "split": split, "kinds": dict(sorted(kinds.items()))}


def plot_order_failures(ds, study: dict, row: str, path: Path, n_scenes: int = 4) -> dict:
    """Why the order choice fails: up to ``n_scenes`` scenes of ``ds`` (val) that the order-study row ``row``
    (``albedo/normals[+noise model]``, read with its scene records) got wrong by the evidence, the first of each
    kind of error (true order, chosen order), fitted again as the study fitted them. Per scene: the noisy image, the
    pixels fitted, the residual of the true order's best candidate and of the chosen one, and their difference (what
    the chosen model's extra or missing SH terms fit).  Returns ``{"row", "scenes": [{index, true_order, chosen,
    evidence_gain}]}`` (the chosen candidate's log evidence over the true order's best); ``{}`` where the row has
    no such scene."""
    from disent.images import pyplot

    plt = pyplot()

    records = study["order"].get(f"val/{row}", {}).get("scenes")
    if not records:
        return {}
    pairs = list(zip(records["true_order"], records["evidence"]))
    first = {p: k for k, p in reversed(list(enumerate(pairs))) if p[0] != p[1]}  # each kind of error's first scene
    wrong = sorted(first.values())[:n_scenes]
    if not wrong:
        return {}
    fig, axes = plt.subplots(len(wrong), 5, figsize=(11, 2.4 * len(wrong)), squeeze=False)
    out = []
    for ax, k in zip(axes, wrong):
        order, i = records["true_order"][k], records["index"][k]
        item, data, scores, truth, chosen, residuals = refit_study_scene(ds, study, row, "val", k)
        picture = np.full((2, *data.shape), np.nan)
        for j, name in enumerate((truth, chosen)):
            picture[j].flat[data.index] = residuals[name].mean(1)
        gain = scores[chosen]["log_evidence"] - scores[truth]["log_evidence"]
        out.append({"index": i, "true_order": order, "chosen": scores[chosen]["order"], "evidence_gain": gain})
        mask = np.zeros(data.shape)
        mask.flat[data.index] = 1
        ax[0].imshow(item["image"].permute(1, 2, 0).clamp(0, 1).numpy())
        ax[0].set_title(f"val face {i}, true order {order}", fontsize=8)
        ax[1].imshow(mask, cmap="gray")
        ax[1].set_title(f"pixels fitted ({len(data.y)})", fontsize=8)
        limit = np.nanpercentile(np.abs(picture), 99)
        titles = (
            f"residual, order {order} ({truth})",
            f"residual, chosen order ({chosen})",
            "difference: what it fits",
        )
        for a, image, title in zip(ax[2:], (picture[0], picture[1], picture[0] - picture[1]), titles):
            a.imshow(image, cmap="RdBu", vmin=-limit, vmax=limit)
            a.set_title(title + (f"\nlog evidence {gain:+.0f} over order {order}" if a is ax[4] else ""), fontsize=8)
        for a in ax:
            a.axis("off")
    fig.suptitle(
        f"{row}\nval scenes the evidence got wrong (channel-mean residual; red: the image brighter than the fit)",
        fontsize=9,
    )
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return {"row": row, "scenes": out}


def plot_registration(ds, path: Path, n_scenes: int = 4, noise: float = 0.02, n_components: int = 20) -> dict:
    """The texture model's fitted albedo on the eroded pseudo mask, reached through the pseudo uv, the registered
    uv (:func:`disent.lighting.texture.register`) and the true uv, beside the image and the true albedo, for val
    scenes under order-1 light; each panel titled with its uv error (rms, pixels).  Returns those errors."""
    from disent.images import pyplot

    plt = pyplot()

    from disent.lighting.order import score
    from disent.lighting.texture import texture_for

    columns = {"normal_pseudo_eroded": "pseudo uv", "normal_pseudo_registered": "registered uv", "oracle_uv": "true uv"}
    fig, axes = plt.subplots(n_scenes, 2 + len(columns), figsize=(2.0 * (2 + len(columns)), 2.1 * n_scenes))
    errors = {c: [] for c in columns}
    for i in range(n_scenes):
        item = ds.sample(i, sh=light_of_order(ds[i]["sh"], 1))
        data = item_data(item, noise, 1000 + i, known_albedo=False, normals="normal_pseudo_eroded")
        truth = item["uv"].double().flatten(1)[:, data.index]
        H, W = data.shape
        panels = [(item["image"].permute(1, 2, 0).clamp(0, 1).numpy(), "image")]
        for c, label in columns.items():  # geometries with the same normals and mask, each with its uv
            uv = uv_of(item, data, c, n_components)
            tex, variance = texture_for(data, uv, n_components)
            beta = np.array(score(data, 2, texture=(tex, variance))["texture"])
            canvas = np.zeros((H * W, 3))
            canvas[data.index] = np.clip(tex[0] + np.einsum("j,jpc->pc", beta, tex[1:]), 0, None)
            canvas /= max(canvas.max(), 1e-6)
            rms = float(((uv.double().flatten(1)[:, data.index] - truth) ** 2).sum(0).mean().sqrt() * (W - 1) / 2**0.5)
            errors[c].append(rms)
            panels.append((canvas.reshape(H, W, 3), f"{label}, {rms:.1f} px"))
        albedo = item["albedo"].permute(1, 2, 0).numpy()
        panels.append((albedo / max(albedo.max(), 1e-6), "true albedo"))
        for ax, (img, title) in zip(axes[i], panels):
            ax.imshow(img)
            ax.set_title(title, fontsize=8)
            ax.axis("off")
    fig.suptitle("texture model fitted through each uv (eroded pseudo mask; uv error rms per axis, pixels)", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return {c: float(np.mean(v)) for c, v in errors.items()}
