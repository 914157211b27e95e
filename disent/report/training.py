"""Sections on the trained runs: the runs, floor and ceiling, the teaser, the training recipe, learning curves."""

from __future__ import annotations

import math
import shutil
from itertools import combinations
from pathlib import Path

import numpy as np

from disent.images import image_grid, on_matte, over_max, pyplot, save_figure
from disent.report.document import Report
from disent.report.pictures import test_batch
from disent.report.tables import (
    INFER_SPEED_KEY,
    MODELS,
    by_setting_and_model,
    fmt_value,
    is_recipe_run,
    ladder_runs,
    on_the_ladder,
    seed_spread,
    shipped_run,
    spread_text,
    table_head,
)
from disent.runs import TRAIN_SPEED_KEY, Run, load_chosen, pick_runs, portable, run_speed, setting
from disent.storage import machine_text

ERROR_WHITE = 40.0  # degrees of angular error drawn white in the normals figure


def sec_runs(rep: Report, runs: list[Run]) -> None:
    if not runs:
        rep.note(
            "no run folders under `outputs/` or `multirun/`. Train with `python -m disent` or run the "
            "suite (`ablations/README.md`), then run `python -m disent.report` again."
        )
        return
    cols = (
        "recon_mse",
        "recon_face_psnr",
        "normal_mean",
        "trivial_normal_mean",
        "pseudo_normal_mean",
        "albedo_si_mse",
        "trivial_albedo_si_mse",
        "sh_error",
        "trivial_sh_error",
        "light_shading_si_mse",
        "trivial_light_shading_si_mse",
    )

    def f(v):
        return "–" if v is None else f"{v:.4g}"

    head = table_head("run", "setting", "variant", "seed", "status", "machine", "train img/s", "infer img/s", *cols)
    rows = [
        f"| {r.id} | `{setting(r, drop_model=True)}` | {r.variant} | {r.seed} | {r.status} | "
        f"{machine_text(r.machine) if r.machine else '–'} | {f(run_speed(r, TRAIN_SPEED_KEY))} | "
        f"{f(run_speed(r, INFER_SPEED_KEY))} | " + " | ".join(f(r.value(c)) for c in cols) + " |"
        for r in sorted(runs, key=lambda r: (setting(r, drop_model=True), r.variant, str(r.seed), r.id))
    ]
    rep.add(*head, *rows)
    rep.add(
        "",
        "_`trivial_*`: the dataset-mean normal map, albedo map and light on the same test images "
        "(`disent/eval/trivial.py`); a layer counts as learned only where it beats them. Normals, albedo and "
        "`light_shading_si_mse` (the light's shading through the true normals) are scored on the face inside "
        "the pseudo mask, the model's own foreground; `sh_error` on the 27 SH coefficients, including the "
        "directions a face's normals cannot reveal._\n",
    )
    rep.add(*replicate_lines(runs))


REPLICATE_KEYS = (  # (metric, its label, format): what the replicate table compares
    ("normal_mean", "normals (deg)", ".2f"),
    ("recon_face_psnr", "face PSNR (dB)", ".2f"),
    ("albedo_si_mse", "albedo si-MSE", ".5f"),
)


AGREE = 1e-6  # a seed's runs agree where each metric matches to this relative tolerance (float noise)


def agree(runs: list[Run]) -> bool:
    """Whether one seed's ``runs`` give each metric of :data:`REPLICATE_KEYS` as the first does, up to float noise
    (:data:`AGREE`); a missing value agrees with nothing."""
    first, *rest = ([math.nan if (v := r.value(k)) is None else v for k, _, _ in REPLICATE_KEYS] for r in runs)
    return all(math.isclose(a, b, rel_tol=AGREE) for other in rest for a, b in zip(first, other))


def replicate_lines(runs: list[Run]) -> list[str]:
    """The settings with a seed trained more than once (at another revision or on another machine; every table
    averages a seed's runs into one value): per setting and model, the largest gap between one seed's runs beside
    the spread across seeds, and how many of those seeds gave the same numbers each time (:data:`AGREE`)."""
    done = [r for r in runs if r.status == "ok" and r.eval and r.seed is not None]
    rows = []
    for (where, model), rs in sorted(by_setting_and_model(done).items()):
        seeds: dict = {}
        for r in rs:
            seeds.setdefault(r.seed, []).append(r)
        again = [v for v in seeds.values() if len(v) > 1]
        if not again:
            continue
        cells = []
        for key, _, fmt in REPLICATE_KEYS:
            values = [[x for r in v if (x := r.value(key)) is not None] for v in again]
            gap = max((max(vs) - min(vs) for vs in values if len(vs) > 1), default=None)
            spread = seed_spread(rs, key)
            cells.append(f"{fmt_value(gap, fmt)} / {fmt_value(spread['std'] if spread else None, fmt)}")
        same = sum(agree(v) for v in again)  # seeds the revisions trained the same way
        revisions = len({r.revision for v in again for r in v} - {None})
        rows.append(
            f"| `{where}` | {model} | {len(again)} of {len(seeds)} | {sum(map(len, again))} | {revisions} | "
            + " | ".join(cells)
            + f" | {same} of {len(again)} |"
        )
    if not rows:
        return []
    head = table_head(
        "setting",
        "model",
        "seeds run again",
        "their runs",
        "revisions",
        *(f"{label}: largest gap / seed spread" for _, label, _ in REPLICATE_KEYS),
        "seeds whose runs agree (to 6 digits)",
    )
    return [
        "Replicates: seeds trained more than once (the same setting again at a later revision or on another "
        "machine). Every table averages a seed's runs into one value; the largest gap between one seed's runs "
        "beside the spread across seeds (std) says whether that hides a change the revisions made. *Revisions*: "
        "how many git revisions trained them (a record without `git.txt` counts as none); a seed whose runs "
        "agree to 6 significant digits on every metric was trained the same way by each revision.\n",
        *head,
        *rows,
        "",
    ]


CEILING_COLUMNS = (
    ("normal_mean", "normals (deg)", ".2f"),
    ("shading_si_mse", "shading si-MSE", ".4f"),
    ("albedo_si_mse", "albedo si-MSE", ".4f"),
    ("albedo_coarse_si_mse", "albedo: coarse", ".4f"),
    ("albedo_fine_si_mse", "albedo: detail", ".4f"),
    ("light_shading_si_mse", "light on the face", ".4f"),
    ("sh_error", "SH error", ".3f"),
)


def sec_ceiling(rep: Report, runs: list[Run]) -> None:
    """Each layer between its floor (the dataset mean) and its ceiling (the same network trained on the truth)."""
    ceiling = [r for r in runs if r.status == "ok" and r.eval and r.ceiling]
    if not ceiling:
        rep.note(
            "no finished ceiling run among the records; the tables the last build with them published are on "
            "[the archive page](archive.md). Train one with `python -m disent loss=ceiling` (and "
            "`+experiment=long loss=ceiling`) and give the report its folder (`--roots`)."
        )
        return
    with_ceiling = {setting(r, drop_model=True, drop=("loss=",)) for r in ceiling}  # trained settings with a ceiling
    trained = [
        r
        for r in runs
        if r.status == "ok" and r.eval and r.plain and (on_the_ladder(r) or setting(r, drop_model=True) in with_ceiling)
    ]
    rep.add(
        "Where a trained model's layer lies between its **floor**, the dataset-mean map or light "
        "(`disent.eval.trivial`), and its **ceiling**: the same network, optimiser, schedule, batch and data "
        "order trained on SynthFaces' true albedo, normals and light in place of the paper's objective "
        "(`python -m disent loss=ceiling`, `conf/loss/ceiling.yaml`). The paper's models see no albedo and only "
        "the pseudo-GT's normals and L-hat, so the gap to the ceiling is what the missing supervision costs at "
        "that budget, and the ceiling is what the architecture reaches there at all. The rendered face A (.) S "
        "matches the image closely, so the albedo's error follows the shading's (compare the two columns): "
        "an albedo can only be as right as the normals and light that shade it. The albedo's error is split by "
        "scale: *coarse*, its Gaussian blur (2 px, inside the scored region), and *detail*, what the blur leaves "
        "(eyes, brows, lips, pores; the two add up to the total but for twice their inner product; "
        "`disent.eval.metrics.scale_invariant_mse_bands`). Test split, 256 images; "
        "mean ± std over seeds.\n",
        *table_head("model", "row", "setting", "steps", *(label for _, label, _ in CEILING_COLUMNS)),
    )
    gaps, reach = [], []
    for model in ("explicit", "implicit"):
        more = ceiling_rows(rep, model, ceiling, trained)
        gaps, reach = gaps + more[0], reach + more[1]
    if gaps:
        rep.add(
            "",
            "Share of the floor-to-ceiling gap the trained models close, against the ceiling of their setting:\n",
            *gaps,
        )
    if reach:
        rep.add(
            "",
            "What each ceiling removes of the dataset-mean map's albedo error, by scale (detail the ceiling keeps is "
            "out of reach of the paper's objective at that budget too):\n",
            *reach,
        )
    rep.add(
        "",
        "_Regenerate: `python -m disent model=MODEL loss=ceiling` and `python -m disent model=MODEL "
        "+experiment=long loss=ceiling`, then `python -m disent.report --roots ...` with their folders._\n",
    )


def ceiling_rows(rep: Report, model: str, ceiling: list[Run], trained: list[Run]) -> tuple[list[str], list[str]]:
    """One model's rows of the floor-and-ceiling table (the floor, then each setting's trained and ceiling runs by
    budget); returns the lines on the share of the gap the trained runs close, and on what each ceiling removes of
    the floor's albedo error by scale."""
    gaps, reach = [], []
    rows = [("ceiling", r) for r in ceiling if r.model == model] + [("trained", r) for r in trained if r.model == model]
    if not any(kind == "ceiling" for kind, _ in rows):
        return [], []
    floor = next(r for kind, r in rows if kind == "ceiling")  # any run scores the same dataset means
    rep.add(
        f"| {model} | floor (dataset mean) | – | – | "
        + " | ".join(fmt_value(floor.value("trivial_" + k), fmt) for k, _, fmt in CEILING_COLUMNS)
        + " |"
    )
    groups: dict = {}
    for kind, r in rows:
        groups.setdefault((kind, setting(r, drop_model=True)), []).append(r)
    steps = {g: (seed_spread(rs, "steps") or {"mean": math.nan})["mean"] for g, rs in groups.items()}
    order = sorted(groups.items(), key=lambda g: (steps[g[0]], g[0][0] == "ceiling"))
    for (kind, where), rs in order:
        rep.add(
            f"| {model} | {kind} | `{where}` | {steps[kind, where]:,.0f} | "
            + " | ".join(spread_text(seed_spread(rs, k), fmt) for k, _, fmt in CEILING_COLUMNS)
            + " |"
        )
    tops: dict = {}  # each ceiling by the setting of the trained runs at its budget: its overrides but loss=ceiling
    for kind, r in rows:
        if kind == "ceiling":
            tops.setdefault(setting(r, drop_model=True, drop=("loss=",)), []).append(r)
    for (kind, where), rs in order:  # what the ceiling itself removes of the floor's albedo error, by scale
        if kind != "ceiling":
            continue
        shares = []
        for k, band in (("albedo_coarse_si_mse", "coarse part"), ("albedo_fine_si_mse", "detail")):
            lo, got = floor.value("trivial_" + k), seed_spread(rs, k)
            if lo and got:
                shares.append(f"{100 * (1 - got['mean'] / lo):.0f} % of its {band}")
        if shares:
            reach.append(f"- {model}, `{where}` ({steps[kind, where]:,.0f} steps): {' and '.join(shares)}")
    for (kind, where), rs in order:
        top = tops.get(where)
        if kind != "trained" or not top:
            continue
        closed = []
        for k, label, _ in CEILING_COLUMNS:
            lo, got, hi = floor.value("trivial_" + k), seed_spread(rs, k), seed_spread(top, k)
            if None in (lo, got, hi) or lo == hi["mean"]:
                closed.append(f"{label} –")
            else:
                closed.append(f"{label} {100 * (lo - got['mean']) / (lo - hi['mean']):.0f} %")
        top_steps = (seed_spread(top, "steps") or {"mean": math.nan})["mean"]
        unequal = f" (trained {steps[kind, where]:,.0f} steps, ceiling {top_steps:,.0f})"
        gaps.append(f"- {model}, `{where}`: {', '.join(closed)}" + (unequal if steps[kind, where] != top_steps else ""))
    return gaps, reach


def trained_as(source: Run | str) -> tuple[str, str]:
    """What a teaser's model is (its setting, seed and steps) and where it was trained, for a run or the name of a
    shipped model (its manifest: the config, steps and run folder it was trained in)."""
    if isinstance(source, Run):
        what = f"`{setting(source, drop_model=True)}`, seed {source.seed}, {source.value('steps') or 0:,.0f} steps"
        return what, f"run {source.name}"
    from disent.models.shipped import manifest

    entry = manifest()[source]
    seed, steps = entry["cfg"].get("seed"), entry["steps"]
    what = f"shipped weights, `{setting(shipped_run(source), drop_model=True)}`, seed {seed}, {steps:,} steps"
    return what, f"`disent/weights/{entry['file']}`, trained as run {portable(str(entry['run']))}"


def scores(source: Run | str):
    """``key -> value`` of a run's metrics (:meth:`Run.value`) or a shipped model's (its manifest's)."""
    if isinstance(source, Run):
        return source.value
    from disent.models.shipped import manifest

    return manifest()[source]["metrics"].get


def sec_teaser(rep: Report, runs: list[Run], n_vis: int) -> None:
    """The three models side by side on the same test faces (the ladder's runs, else the shipped weights), the
    baseline's reconstructions against theirs (paper Fig. 3) and their normals (:func:`normals_figure`)."""
    from disent.models.shipped import manifest

    chosen = pick_runs(ladder_runs(runs))  # the paper's models as configured, side by side from the same runs
    missing = [m for m in MODELS if m not in chosen]
    if len(missing) == len(MODELS) and set(MODELS) <= set(manifest()):  # no ladder run at all: the shipped weights
        chosen = {m: m for m in MODELS}
    elif missing:  # only notes: the published teaser stays
        rep.note(
            f"no finished run with a checkpoint of {', '.join(f'`{m}`' for m in missing)} on the budget ladder "
            "(defaults or `+experiment=long`, no other override); the teaser sets the three models side by side."
        )
        return
    try:
        models, batch = load_chosen(chosen), test_batch(n_vis)
    except (ImportError, FileNotFoundError) as e:  # fall back to the grids the runs saved
        rep.note(f"cannot render from checkpoints ({e}); showing the runs' own sample grids.")
        for name, r in chosen.items():
            pngs = sorted((r.path / "samples").glob("*.png")) if isinstance(r, Run) else []
            if pngs:
                dst = rep.fig / f"teaser_{name}.png"
                shutil.copyfile(pngs[-1], dst)
                rep.image(dst, f"samples of {name}")
        return
    from disent.eval.scoring import predict

    outs = {name: predict(model, batch["image"]) for name, model in models.items()}

    def shown(out, k):  # shading (mean 0.75 by BWS, peaks above 1) divided by each image's maximum
        x = on_matte(out, k)
        return over_max(x) if k == "shading" else x

    for name, out in outs.items():
        what, origin = trained_as(chosen[name])
        rows = [("input", batch["image"])] + [
            (k + (" / max" if k == "shading" else ""), shown(out, k))
            for k in ("recon", "albedo", "normal", "shading", "matte")
            if k in out
        ]
        path = rep.fig / f"teaser_{name}.png"
        image_grid(
            rows,
            path,
            f"{name} ({what.replace('`', '')}) on SynthFaces test images; albedo, normal and shading where its "
            "matte > 0.5",
        )
        rep.add(f"**{name}** ({what}; {origin})\n")
        rep.image(path, f"teaser {name}")
    rec = [("input", batch["image"])] + [(f"{k} recon", outs[k]["recon"]) for k in MODELS if k in outs]
    path = rep.fig / "baseline_vs_ours.png"
    image_grid(rec, path, "Baseline autoencoder against the rendering models (paper Fig. 3)")
    rep.add("### Baseline against ours (paper Fig. 3)\n")
    rep.image(path, "baseline vs ours")
    normals_figure(rep, chosen, outs, batch)


def normals_figure(rep: Report, chosen: dict, outs: dict, batch: dict) -> None:
    """The models' normals against the pseudo-GT and the truth, their angular errors, and the table of each one's
    normal error beside the mean map's and the pseudo-GT's."""
    from disent.eval.metrics import angular_error_deg
    from disent.regions import decomposed_region

    nrm = [
        ("input", batch["image"]),
        ("normal true", batch["normal"] * batch["matte"]),
        ("normal pseudo-GT", batch["normal_pseudo"] * batch["mask_pseudo"]),
    ]
    with_normals = [k for k in MODELS if k in outs and "normal" in outs[k]]
    nrm += [(f"normal {k}", on_matte(outs[k], "normal")) for k in with_normals]
    scored = decomposed_region(batch)  # the angular error where it is scored, black 0 to white ERROR_WHITE degrees

    def error(normal):
        return (angular_error_deg(normal, batch["normal"])[:, None] / ERROR_WHITE).clamp(0, 1) * scored

    nrm += [("error pseudo-GT", error(batch["normal_pseudo"]))]
    nrm += [(f"error {k}", error(outs[k]["normal"])) for k in with_normals]
    path = rep.fig / "normals.png"
    image_grid(
        nrm,
        path,
        "Our normals against the pseudo-GT they were trained on and the true normals; their angular error on the "
        f"scored pixels (black 0, white >= {ERROR_WHITE:g} deg)",
    )
    rep.add("### Our normals against the pseudo-GT and the truth\n")
    rep.image(path, "normals")
    rows = [(n, value) for n, r in chosen.items() if (value := scores(r))("normal_mean") is not None]
    if rows:
        rep.add(
            *table_head(
                "model (the teaser's weights, one run)",
                "normal error (deg)",
                "dataset-mean map (deg)",
                "pseudo-GT error, same pixels (deg)",
                "under 25° ours / pseudo",
            ),
        )
        for n, value in rows:
            what = "shipped weights" if isinstance(chosen[n], str) else f"run {chosen[n].name}"
            rep.add(
                f"| {n} ({what}) | {value('normal_mean'):.2f} | {value('trivial_normal_mean') or float('nan'):.2f} | "
                f"{value('pseudo_normal_mean') or float('nan'):.2f} | "
                f"{value('normal_under_25') or float('nan'):.3f} / "
                f"{value('pseudo_normal_under_25') or float('nan'):.3f} |"
            )
        rep.add(
            "",
            '_The paper\'s claim "beyond the 3DMM subspace" holds for a run when its error is below the '
            "pseudo-GT's on the same pixels; claim 1's verdicts read every seed (the claims page)._\n",
        )


RECIPE_COLUMNS = (
    ("normal_mean", "normals (deg)", ".2f"),
    ("recon_face_psnr", "face PSNR (dB)", ".2f"),
    ("albedo_si_mse", "albedo si-MSE", ".4f"),
    ("sh_error", "SH error", ".3f"),
)


def sec_recipe(rep: Report, runs: list[Run]) -> None:
    """The training recipe's leave-one-out table: run folders under a ``recipe/`` folder, one per variant
    (folder name), ``recipe/recipe`` the full recipe; each row changes one setting back (overrides column)."""
    rows = {r.id: r for r in runs if is_recipe_run(r) and r.eval}
    ref = rows.get("recipe")
    if ref is None:
        rep.note(
            "no `recipe/recipe` run among the records (ablations/recipe.sh writes the leave-one-out runs); the table "
            "the last build with them published is on [the archive page](archive.md)."
        )
        return
    steps, batch = ref.eval.get("steps"), (ref.cfg.get("train") or {}).get("batch_size")
    rep.add(
        f"Each row trains the explicit model for the same {steps} steps of batch {batch} with one setting of the "
        "recipe changed back (the override column), and scores it on the same 256 test images. "
        "Lower is better except for PSNR. The trivial and pseudo-GT rows score the dataset-mean map or light and the "
        "morphable-model fit on the same images.\n"
    )
    rep.add(
        *table_head("variant", "override", "steps", *(c[1] for c in RECIPE_COLUMNS), "train min"),
    )

    def cell(r, key, fmt):
        v, base = r.eval.get(key), ref.eval.get(key)
        if v is None:
            return "–"
        old = key.startswith("albedo") and "albedo_face_si_mse" not in r.eval  # scored before the region change
        return f"{v:{fmt}}" + ("†" if old else "") + ("" if r is ref or base is None else f" ({v - base:+{fmt}})")

    for name in ["recipe", *sorted(n for n in rows if n != "recipe")]:
        r = rows[name]
        changed = [o for o in map(str, r.overrides) if o not in map(str, ref.overrides)]
        rep.add(
            f"| {name} | {' '.join(f'`{o}`' for o in changed) or '–'} | {r.eval.get('steps')} | "
            + " | ".join(cell(r, k, f) for k, _, f in RECIPE_COLUMNS)
            + f" | {(r.eval.get('train_seconds') or 0) / 60:.1f} |"
        )
    e = ref.eval
    rep.add(
        f"| trivial (dataset mean) | – | – | {e.get('trivial_normal_mean', float('nan')):.2f} | – | "
        f"{e.get('trivial_albedo_si_mse', float('nan')):.4f} | {e.get('trivial_sh_error', float('nan')):.3f} | – |",
        f"| pseudo-GT | – | – | {e.get('pseudo_normal_mean', float('nan')):.2f} | – | – | "
        f"{e.get('pseudo_sh_error', float('nan')):.3f} | – |",
        "",
    )
    if any("albedo_face_si_mse" not in r.eval for r in rows.values()):
        rep.add(
            "† scored over the whole true face mask (hair and neck included) by an earlier version; today's "
            "`albedo_si_mse` covers the face inside the pseudo mask (`python -m disent.eval.evaluate RUN` "
            "scores a run again where its checkpoint still loads).\n"
        )


CURVE_PANELS = (  # (val key, trivial key, pseudo-GT key, label); every panel: lower is better except PSNR
    ("normal_mean", "trivial_normal_mean", "pseudo_normal_mean", "normal error (deg)"),
    ("albedo_si_mse", "trivial_albedo_si_mse", None, "albedo scale-inv. MSE"),
    ("sh_error", "trivial_sh_error", "pseudo_sh_error", "SH error"),
    (
        "light_shading_si_mse",
        "trivial_light_shading_si_mse",
        "pseudo_light_shading_si_mse",
        "light on the face (si-MSE)",
    ),
    ("recon_face_psnr", None, None, "face PSNR (dB)"),
)


def val_curves(run: Run) -> list[dict]:
    """The run's periodic ``val`` records, each with ``images`` (step x batch) and ``minutes`` (training wall).
    Albedo values written before the albedo was scored inside the pseudo mask (records without
    ``albedo_face_si_mse``) are left out, so that one line never mixes two definitions."""
    batch = (run.cfg.get("train") or {}).get("batch_size") or 1
    albedo = ("albedo_si_mse", "albedo_global_si_mse", "trivial_albedo_si_mse", "trivial_albedo_global_si_mse")
    out = []
    for r in run.metrics:
        if isinstance(r.get("val"), dict):
            v = {**r["val"], "images": r["step"] * batch, "minutes": r["wall"] / 60}
            if "albedo_face_si_mse" not in v:
                v = {k: x for k, x in v.items() if k not in albedo}
            out.append(v)
    return out


def trained_on_gpu(run: Run) -> str | None:
    """The GPU ``run`` trained on (its ``machine.json``), or None for a CPU run or one that recorded no machine."""
    return (run.machine or {}).get("gpu")


def curve_label(run: Run) -> str:
    """A learning curve's legend label: the seeds of a setting share it; a GPU run names its GPU (its wall minutes
    are not the CPU's)."""
    gpu = trained_on_gpu(run)
    return f"{run.variant}: {setting(run, drop_model=True)}" + (f" ({gpu})" if gpu else "")


def mark_off_chart(ax, ends: list[tuple[float, float, str]]) -> list[float]:
    """An arrow at the top edge of ``ax``, labelled with the value, for each line end ``(x, y, colour)`` above the
    panel's y limit: a run that broke far above the reference lines is named, not silently clipped. Ends within 5%
    of the x range of each other share one label (``"64.1, 80.9"``), in their colour where they share one, else dark
    gray. Returns the values marked."""
    top, (x0, x1) = ax.get_ylim()[1], ax.get_xlim()
    marked = sorted((x, y, c) for x, y, c in ends if y > top)
    groups = []
    for end in marked:
        if groups and end[0] - groups[-1][-1][0] < 0.05 * (x1 - x0):
            groups[-1].append(end)
        else:
            groups.append([end])
    for group in groups:
        colours = {c for _, _, c in group}
        colour = colours.pop() if len(colours) == 1 else "0.2"  # ends of different lines: a neutral label
        x = float(np.mean([x for x, _, _ in group]))
        side = (x - x0) / (x1 - x0)  # a label near a side of the panel runs inwards, not over the edge
        ax.annotate(
            ", ".join(f"{y:.3g}" for y in sorted(y for _, y, _ in group)),
            xy=(x, top),
            xytext=(0, -14),
            textcoords="offset points",
            ha="left" if side < 0.15 else "right" if side > 0.85 else "center",
            fontsize=7,
            color=colour,
            arrowprops={"arrowstyle": "->", "color": colour, "lw": 0.8},
        )
    return [y for _, y, _ in marked]


def plot_learning_curves(runs: list[Run], path: Path, title: str = "", colour_by_setting: bool = False) -> bool:
    """Each accuracy of the ``val`` records against training images (top) and wall minutes (bottom), one
    line per run (a colour and a legend entry per model, or per model and setting; dash-dotted for a ceiling run,
    thick for a GPU run), with the trivial (dataset-mean) baseline dashed and the pseudo-GT dotted."""
    curves = [(r, val_curves(r)) for r in runs]
    curves = [(r, c) for r, c in curves if c]
    if not curves:
        return False
    plt = pyplot()
    fig, axes = plt.subplots(2, len(CURVE_PANELS), figsize=(4 * len(CURVE_PANELS), 6.4), squeeze=False)

    def kind(r):  # what shares a colour and a legend entry: the model (and ablation), or each setting
        return curve_label(r) if colour_by_setting else r.variant.removesuffix("+ceiling")

    kinds = sorted({kind(r) for r, _ in curves})
    palette = [f"C{i}" for i in range(10)] if len(kinds) <= 10 else list(plt.get_cmap("tab20").colors)
    for col, (key, trivial, pseudo, label) in enumerate(CURVE_PANELS):
        for row, x in enumerate(("images", "minutes")):
            ax = axes[row][col]
            seen, ends = set(), []
            for r, c in curves:
                pts = [(v[x], v[key]) for v in c if v.get(key) is not None]
                if not pts or (r.ceiling and key == "recon_face_psnr"):  # a ceiling does not train the reconstruction
                    continue
                name = kind(r)
                colour = palette[kinds.index(name) % len(palette)]  # one colour each, up to 20
                ends.append((*pts[-1], colour))
                ax.plot(
                    *zip(*pts),
                    color=colour,
                    ls="-." if r.ceiling else "-",
                    lw=2.0 if trained_on_gpu(r) else 1.0,
                    label=None if name in seen else name,
                )
                seen.add(name)
            lines = []
            for ref, style, name in ((trivial, "--", "dataset mean"), (pseudo, ":", "pseudo-GT")):
                vals = [
                    c[-1][ref] for _, c in curves if ref and c[-1].get(ref) is not None and c[-1].get(key) is not None
                ]
                if vals:
                    lines.append(float(np.mean(vals)))
                    ax.axhline(lines[-1], color="k", ls=style, lw=1, label=name)
            if lines and key != "recon_face_psnr":  # the first steps' errors would squash the curves that matter;
                top = max(lines)  # a run that ends far above the reference lines (it broke) stays in view, up to 3x;
                finals = [y for _, y, _ in ends]  # beyond that an arrow at the top edge names its final value
                ax.set_ylim(top=max(1.5 * top, min(1.1 * max(finals, default=0), 3 * top)))
                mark_off_chart(ax, ends)
            ax.set_xlabel("training images" if x == "images" else "training wall minutes")
            if x == "images":  # 250000 runs into its neighbours: 250k
                ax.xaxis.set_major_formatter(lambda v, _: f"{v / 1000:g}k" if v else "0")
            ax.set_ylabel(label)
            ax.grid(alpha=0.3)
    legend = {}  # one legend under the panels: every line's label (the baseline has a curve in the PSNR panels only)
    for ax in axes[0]:
        for handle, label in zip(*ax.get_legend_handles_labels()):
            legend.setdefault(label, handle)
    rows = (len(legend) + 3) // 4
    fig.set_figheight(6.4 + 0.2 * rows)  # the panels keep their height; the legend adds its rows
    fig.legend(legend.values(), legend.keys(), loc="lower center", ncol=4, fontsize=7, frameon=False)
    if title:
        fig.suptitle(title, fontsize=9)
    fig.tight_layout(rect=(0, (0.2 * rows + 0.1) / (6.4 + 0.2 * rows), 1, 1))
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    save_figure(fig, path, dpi=110, bbox_inches="tight")  # a legend wider than the panels is not clipped
    return True


def sec_learning_curves(rep: Report, runs: list[Run]) -> None:
    drawn = False
    ablated = {setting(r, drop=("ablation=",)) for r in runs if r.ablations and not is_recipe_run(r)}
    ladder = [r for r in runs if r.plain and on_the_ladder(r)]
    ceilings = {setting(r, drop_model=True) for r in ladder}
    ladder += [r for r in runs if r.ceiling and setting(r, drop_model=True, drop=("loss=",)) in ceilings]
    others = [r for r in runs if r.plain and not on_the_ladder(r) and not is_recipe_run(r)]
    defaults = [r for r in ladder if r.plain and r.model == "explicit" and setting(r, drop_model=True) == "(defaults)"]
    for name, subset, title, by_setting in (
        ("learning_curves.png", ladder, "the budget ladder and its ceilings: validation accuracy in training", True),
        (
            "learning_curves_settings.png",
            others + (defaults if others else []),
            "every other setting (A/B runs, earlier recipes) beside the explicit defaults",
            True,
        ),
        (  # each ablation beside the full model of the setting it ablates
            "learning_curves_ablations.png",
            [
                r
                for r in runs
                if not is_recipe_run(r)
                and (r.ablations or (r.model == "explicit" and r.plain and setting(r) in ablated))
            ],
            "the ablations beside the full explicit model, a colour each at every rung (the longer lines: the longer "
            "rung)",
            False,
        ),
        (
            "learning_curves_recipe.png",
            [r for r in runs if is_recipe_run(r)],
            "the training recipe's leave-one-out",
            True,
        ),
    ):
        path = rep.fig / name
        if plot_learning_curves(subset, path, f"{title} (64 val images)", by_setting):
            rep.image(path, title)
            drawn = True
    if not drawn:
        rep.note("no run logged `val` records (`train.val_every`).")
        return
    rep.add(
        "_A layer counts as learned only below its dashed line (the dataset-mean map or light, "
        "`disent.eval.trivial`); the dotted line is the pseudo ground truth that supervised it. Thick lines: runs "
        "trained on a GPU (their wall minutes are the GPU's); dash-dotted: the supervised ceiling._\n"
    )


# ----------------------------------------------------------------------------- the implicit model's UV map by seed

UV_EARLY_STEP = 1000  # E_UV's training loss read around this step (+-250): by then a seed's UV map has learned or not


def logged_mean(run: Run, key: str, lo: float, hi: float) -> float | None:
    """The mean of the training log's ``key`` over the steps ``lo`` to ``hi``; None where none was logged."""
    vals = [r[key] for r in run.metrics if lo <= r.get("step", -1) <= hi and isinstance(r.get(key), (int, float))]
    return float(np.mean(vals)) if vals else None


def concordance(pairs: list[tuple]) -> tuple[int, int]:
    """Of the pairs ``((x1, y1), (x2, y2))`` with ``x1 != x2``, how many order ``y`` as they order ``x``, and how
    many there are: (concordant, compared)."""
    compared = [((a[0] - b[0]) * (a[1] - b[1])) for a, b in pairs if a[0] != b[0] and None not in (a[1], b[1])]
    return sum(d > 0 for d in compared), len(compared)


def within_setting_pairs(groups: dict, x: str, y: str) -> list[tuple]:
    """Every pair of runs of one setting as ``((x, y), (x, y))`` from their eval.json."""
    return [
        ((a.eval[x], a.eval.get(y)), (b.eval[x], b.eval.get(y)))
        for rs in groups.values()
        for a, b in combinations(rs, 2)
    ]


def data_baseline(runs: list[Run], key: str) -> float | None:
    """A baseline that depends on the test faces alone (``trivial_uv_error``, ``pseudo_uv_error``), from the runs
    scored with it: their median (None where none was)."""
    vals = [r.eval[key] for r in runs if isinstance(r.eval.get(key), (int, float))]
    return float(np.median(vals)) if vals else None


def uv_groups(runs: list[Run]) -> dict:
    """``{setting: runs}`` of the finished implicit runs that scored their UV map, in order of setting and seed."""
    uv = [r for r in runs if r.model == "implicit" and r.status == "ok" and "uv_error" in (r.eval or {})]
    groups = by_setting_and_model(sorted(uv, key=lambda r: str(r.seed)))  # each run's setting read once
    return {where: groups[where, model] for where, model in sorted(groups)}


def plot_uv_by_seed(groups: dict, baselines: dict, path: Path) -> None:
    """Left: E_UV's training loss against the step, a line per run coloured by its UV map's test error; right: that
    error against the normals' error, a marker per setting, with the mean and pseudo UV maps' errors as lines."""
    plt = pyplot()
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4.4))
    errors = [r.eval["uv_error"] for rs in groups.values() for r in rs]
    norm = plt.Normalize(0, max(max(errors), baselines.get("trivial") or 0))
    cmap = plt.get_cmap("viridis")
    markers = "osD^v<>ph*"
    for i, (label, rs) in enumerate(groups.items()):
        for r in rs:
            pts = [(m["step"], m["UV"]) for m in r.metrics if isinstance(m.get("UV"), (int, float))]
            if pts:
                left.plot(*zip(*pts), color=cmap(norm(r.eval["uv_error"])), lw=0.8, alpha=0.8)
        right.scatter(
            [r.eval["uv_error"] for r in rs],
            [r.eval["normal_mean"] for r in rs],
            marker=markers[i % len(markers)],
            color=f"C{i % 10}",
            label=label,
        )
        for r in rs:
            right.annotate(
                f"s{r.seed}",
                (r.eval["uv_error"], r.eval["normal_mean"]),
                fontsize=7,
                xytext=(3, 2),
                textcoords="offset points",
            )
    left.set_xscale("log")  # a stalled UV map stalls in its first few hundred steps, at every budget
    left.set_yscale("log")
    left.set_xlabel("training step (log scale)")
    left.set_ylabel("E_UV, training loss (MSE to the pseudo UV)")
    fig.colorbar(plt.cm.ScalarMappable(norm=norm, cmap=cmap), ax=left, label="its UV map's test error")
    for key, style, name in (("trivial", "--", "dataset-mean UV map"), ("pseudo", ":", "pseudo UV (its supervision)")):
        if baselines.get(key) is not None:
            right.axvline(baselines[key], color="k", ls=style, lw=1, label=name)
    right.set_xlabel("UV map's test error (UV units)")
    right.set_ylabel("normal error (deg)")
    right.legend(fontsize=6, loc="upper center", bbox_to_anchor=(0.5, -0.14), ncol=2, frameon=False)
    for ax in (left, right):
        ax.grid(alpha=0.3)
    fig.tight_layout()
    save_figure(fig, path, dpi=110, bbox_inches="tight")  # the legend under the panel is not clipped


def sec_uv_by_seed(rep: Report, runs: list[Run]) -> None:
    """Why the implicit model's seeds spread: whether its UV map learned (its test error against the dataset-mean UV
    map and the pseudo UV), read against its normals and albedo, and when in training it was decided."""
    groups = uv_groups(runs)
    if not groups:
        rep.note("no finished implicit run scored its UV map (`uv_error` in eval.json).")
        return
    uv = [r for rs in groups.values() for r in rs]
    base = {"trivial": data_baseline(uv, "trivial_uv_error"), "pseudo": data_baseline(uv, "pseudo_uv_error")}
    rep.add(
        "The implicit model draws its normals and albedo through its UV map (Fig. 2b), which E_UV (Sec. 4.2) pulls "
        "towards the morphable model's UV map. *UV error*: the mean distance of its UV map from the true one on the "
        "scored pixels (UV units, the texture square is 1 wide; `disent.eval.scoring.uv_metrics`), beside the "
        "dataset-mean UV map's (`trivial_uv_error`) and the pseudo UV's, its supervision (`pseudo_uv_error`); "
        f"*E_UV at step {UV_EARLY_STEP:,}*: its training loss, the mean of the logged values within 250 steps of "
        "it, and at the end (its last 250 steps); *normals at the true UV*: its UV-space normals looked up where "
        "the true UV points. Test split, every finished implicit run with a scored UV map, by setting and seed.\n"
    )
    if None in base.values():
        rep.add(
            "_The baselines (`trivial_uv_error`, `pseudo_uv_error`) are in no run's eval.json yet: score a run "
            "again (`python -m disent.eval.evaluate RUN`)._\n"
        )
    path = rep.fig / "uv_by_seed.png"
    plot_uv_by_seed(groups, base, path)
    rep.image(path, "the implicit model's UV map by seed")
    rep.add(
        *table_head(
            "setting",
            "seed",
            f"E_UV at step {UV_EARLY_STEP:,}",
            "E_UV at the end",
            "UV error",
            "normals (deg)",
            "normals at the true UV (deg)",
            "albedo si-MSE",
        )
    )
    for label, rs in groups.items():
        for r in rs:
            end = max((m.get("step", 0) for m in r.metrics), default=0)
            cells = (
                logged_mean(r, "UV", UV_EARLY_STEP - 250, UV_EARLY_STEP + 250),
                logged_mean(r, "UV", end - 250, end),
                r.eval["uv_error"],
                r.eval.get("normal_mean"),
                r.eval.get("normal_at_true_uv_mean"),
                r.eval.get("albedo_si_mse"),
            )
            rep.add(
                f"| {label} | {r.seed} | "
                + " | ".join(fmt_value(v, f) for v, f in zip(cells, (".4f", ".4f", ".3f", ".2f", ".2f", ".4f")))
                + " |"
            )
    rep.add("")
    rep.add(uv_by_seed_reading(groups, base) + "\n")
    rep.add(
        "By setting, mean ± std over its seeds (*UV maps not learned*: the runs whose UV error is above the "
        "dataset-mean UV map's):\n",
        *table_head("setting", "UV error", "UV maps not learned", "normals (deg)", "albedo si-MSE", "face PSNR (dB)"),
    )
    for label, rs in groups.items():
        lost = "–" if base["trivial"] is None else sum(r.eval["uv_error"] > base["trivial"] for r in rs)
        cells = [
            spread_text(seed_spread(rs, k), f)
            for k, f in (
                ("uv_error", ".3f"),
                ("normal_mean", ".2f"),
                ("albedo_si_mse", ".4f"),
                ("recon_face_psnr", ".2f"),
            )
        ]
        rep.add(f"| {label} | {cells[0]} | {lost} of {len(rs)} | " + " | ".join(cells[1:]) + " |")
    rep.add("")


def early_uv_weight(run: Run) -> tuple | None:
    """``(weight, steps)``: E_UV's weight for ``run``'s first steps (``loss.early_weights``), None where it had none."""
    loss = run.cfg.get("loss") or {}
    early, steps = (loss.get("early_weights") or {}).get("UV"), loss.get("early_steps") or 0
    return (early, steps) if early is not None and steps else None


def uv_weight_text(run: Run) -> str | None:
    """E_UV's weight over ``run``'s training: ``1``, or ``10 for 300 steps, then 1`` (``loss.early_weights``)."""
    weight = ((run.cfg.get("loss") or {}).get("weights") or {}).get("UV")
    if weight is None:
        return None
    early = early_uv_weight(run)
    return f"{early[0]:g} for {early[1]:,} steps, then {weight:g}" if early else f"{weight:g}"


def early_weight_lines(runs: list[Run]) -> list[str]:
    """Each run that trained E_UV at an early weight (``loss.early_weights``) beside the runs of its seed and setting
    at one weight throughout (E_UV's weight apart): their UV error and normals."""

    def cells(r):
        return f"UV error {r.eval['uv_error']:.3f}, normals {fmt_value(r.eval.get('normal_mean'), '.2f')} deg"

    lines = []
    for r in filter(early_uv_weight, runs):
        where = setting(r, drop_model=True, drop=("loss.early_", "loss.weights.UV="))
        same = [
            o
            for o in runs
            if o.seed == r.seed
            and not early_uv_weight(o)
            and setting(o, drop_model=True, drop=("loss.weights.UV=",)) == where
        ]
        others = ", ".join(f"weight {uv_weight_text(o)} {cells(o)}" for o in sorted(same, key=uv_weight_text))
        lines.append(
            f"`{where}`, seed {r.seed}, weight {uv_weight_text(r)}: {cells(r)}"
            + (f" (against {others})" if others else "")
        )
    return lines


def uv_by_seed_reading(groups: dict, base: dict) -> str:
    """The section's findings in words, each computed from the runs."""
    runs = [r for rs in groups.values() for r in rs]
    text = []
    if base["trivial"] is not None and base["pseudo"] is not None:
        better = [r for r in runs if r.eval["uv_error"] < base["pseudo"]]
        worse = [r for r in runs if r.eval["uv_error"] > base["trivial"]]
        text.append(
            f"Of {len(runs)} runs, {len(better)} draw a UV map nearer the truth than the pseudo UV that supervised "
            f"it ({base['pseudo']:.3f}), {len(worse)} one farther from it than the dataset-mean UV map "
            f"({base['trivial']:.3f}): a UV layer that has not learned."
        )
    by_seed: dict = {}  # (E_UV's weights over training, seed): UV errors over the settings
    for r in runs:
        by_seed.setdefault((uv_weight_text(r), r.seed), []).append(r.eval["uv_error"])
    spans = [
        f"weight {w}, seed {s}: {min(v):.3f}-{max(v):.3f} over {len(v)}"
        for (w, s), v in sorted(by_seed.items(), key=lambda kv: (str(kv[0][0]), str(kv[0][1])))
        if len(v) > 1 and w is not None
    ]
    if spans:
        text.append(
            "At one weight of E_UV, the seed (the initial weights and the order of the batches) decides it across "
            f"settings (UV error per seed, over its settings: {'; '.join(spans)})."
        )
    early = early_weight_lines(runs)
    if early:
        text.append(f"An early weight of E_UV, against the same seed at one weight throughout: {'; '.join(early)}.")
    for y, what in (("normal_mean", "normal error"), ("albedo_si_mse", "albedo error")):
        agree, n = concordance(within_setting_pairs(groups, "uv_error", y))
        if n:
            text.append(
                f"In {agree} of {n} pairs of runs of one setting, the run with the smaller UV error has the smaller "
                f"{what}."
            )
    early = [(logged_mean(r, "UV", UV_EARLY_STEP - 250, UV_EARLY_STEP + 250), r.eval["uv_error"]) for r in runs]
    early = [e for e in early if e[0] is not None]
    agree, n = concordance(list(combinations(early, 2)))
    if n:
        text.append(
            f"It is settled early: in {agree} of {n} pairs of runs the one with the smaller E_UV at step "
            f"{UV_EARLY_STEP:,} ends with the smaller UV error."
        )
    return " ".join(text)


def uv_glance_lines(runs: list[Run], ladder: list[Run]) -> list[str]:
    """One sentence for the glance: at each rung, how many of the ``ladder``'s implicit runs drew a UV map no nearer
    the truth than the dataset-mean UV map (its error read off ``runs``' evaluations), and their normals beside the
    others'."""
    base = data_baseline([r for r in runs if r.eval], "trivial_uv_error")
    groups = uv_groups(ladder)
    if base is None or not groups:
        return []
    parts = []
    for label, rs in sorted(groups.items()):
        lost = [r for r in rs if r.eval["uv_error"] > base]
        kept = [r for r in rs if r not in lost]
        part = f"`{label}` {len(lost)} of {len(rs)}"
        if lost and kept:
            part += (
                f" (seed(s) {', '.join(str(r.seed) for r in lost)}: normals "
                f"{spread_text(seed_spread(lost, 'normal_mean'))} deg against "
                f"{spread_text(seed_spread(kept, 'normal_mean'))} for the others)"
            )
        parts.append(part)
    return [
        "The implicit model's UV map, scored ladder runs whose UV map is farther from the truth than the "
        f"dataset-mean UV map ({base:.3f}): {'; '.join(parts)}. The section *Stability across seeds* shows when "
        "and why.\n"
    ]
