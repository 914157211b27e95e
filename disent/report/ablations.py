"""Claim 4 and the ablation tables: each ablated piece against the full model, at budgets where the full model
meets its targets."""

from __future__ import annotations

import json

from disent.eval import ablation as _ablation
from disent.eval.metrics import FLAT_SHARE, frame_map, normals_failure
from disent.images import on_matte, pyplot, to_array, wrapped
from disent.report.document import Report
from disent.report.pictures import test_batch
from disent.report.tables import (
    Glance,
    by_setting_and_model,
    fmt_value,
    is_recipe_run,
    seed_spread,
    spread_text,
    table_head,
    verdict,
)
from disent.runs import Run, group_by_setting, joins, load_chosen, pick_runs, run_ref, setting

# What the full explicit model must reach at a budget before ablations there can give verdicts: normal error
# (deg, at most), face PSNR (dB, at least), albedo scale-invariant error (at most this share of the mean map's)
TARGETS = {"normal_mean": 12.5, "recon_face_psnr": 26.0, "albedo_share_of_trivial": 0.5}


def albedo_share(runs: list[Run]) -> float | None:
    """The runs' mean albedo error as a share of their mean map's (the albedo target's measure), or None."""
    albedo, trivial = seed_spread(runs, "albedo_si_mse"), seed_spread(runs, "trivial_albedo_si_mse")
    return albedo["mean"] / trivial["mean"] if albedo and trivial else None


def budget_misses(explicit: list[Run]) -> list[str] | None:
    """The :data:`TARGETS` the full explicit model misses at a budget (the mean over its seeds; empty: it meets
    them all), or None without a finished run there."""
    normal, psnr, share = (
        seed_spread(explicit, "normal_mean"),
        seed_spread(explicit, "recon_face_psnr"),
        albedo_share(explicit),
    )
    if not (normal and psnr and share is not None):
        return None
    misses = []
    if normal["mean"] > TARGETS["normal_mean"]:
        misses.append(
            f"normals {_past(normal['mean'], TARGETS['normal_mean'])} deg (target <= {TARGETS['normal_mean']})"
        )
    if psnr["mean"] < TARGETS["recon_face_psnr"]:
        misses.append(
            f"face PSNR {_past(psnr['mean'], TARGETS['recon_face_psnr'])} dB (>= {TARGETS['recon_face_psnr']})"
        )
    if share > TARGETS["albedo_share_of_trivial"]:
        misses.append(
            f"albedo {_past(share, TARGETS['albedo_share_of_trivial'])} of the mean map's "
            f"(<= {TARGETS['albedo_share_of_trivial']})"
        )
    return misses


def _past(value: float, target: float, digits: int = 2) -> str:
    """``value`` with ``digits`` decimals, or as many more (up to 4) as it takes not to read as ``target`` (a miss
    of 0.5016 against 0.5 reads 0.502, not 0.50)."""
    while digits < 4 and f"{value:.{digits}f}" == f"{target:.{digits}f}":
        digits += 1
    return f"{value:.{digits}f}"


def budget_check(explicit: list[Run]) -> str:
    """:func:`budget_misses` as the caption under an ablation table: where the full explicit model misses a
    target, the ablation differences at that budget are not testable verdicts; where it meets them on an E_recon-L
    target that is not the paper's L-hat (the truth's, or one drawn without truth), the caption says so."""
    from disent.config import loss_setting

    misses = budget_misses(explicit)
    if misses is None:
        return "_Budget check: no finished full explicit run at this budget; verdicts not testable._\n"
    if misses:
        return (
            f"_Budget check: the full explicit model misses {', '.join(misses)}; the ablation differences "
            "at this budget are **not testable** verdicts._\n"
        )
    if any(r.light_oracle for r in explicit):
        return (
            "_Budget check: the full explicit model meets every target at this budget, fed the true light through "
            "E_recon-L's target (an oracle setting, not the paper's model)._\n"
        )
    if other := sorted({loss_setting(r.cfg.get("loss") or {}, "recon_L_target") for r in explicit} - {"sh_pseudo"}):
        return (
            "_Budget check: the full explicit model meets every target at this budget, trained on another E_recon-L "
            f"target than the paper's L-hat (`loss.recon_L_target={', '.join(other)}`; no truth, not the paper's "
            "model)._\n"
        )
    return "_Budget check: the full explicit model meets every target at this budget._\n"


# What the paper says each ablated piece does, read off the test metric where its absence should show:
# (ablation, the paper's reason for the piece, metric; the full model wins where the metric is lower, except PSNR
# and SSIM).  Equation numbers count the paper's numbered equations (E_smooth-A 10, E_smooth-S 11, BWS 14).
ABLATION_CLAIMS = (
    ("no_bws", "BWS: no colour cast in the shading (Eq. 14)", "shading_cast"),
    ("no_bws", "BWS: no degenerate split where A_e takes the shading (Sec. 4.2)", "albedo_shading_corr"),
    ("no_bws", "BWS: the skin's colour stays in A_e, not in S_e (Sec. 4.2)", "albedo_colour_si_mse"),
    ("no_bws", "BWS: S_e keeps the light's colour, not the skin's (Sec. 4.2)", "shading_colour_si_mse"),
    ("no_bws", "BWS: S_e keeps the light's colour, not the skin's (Sec. 4.2)", "shading_albedo_tone_corr"),
    ("no_smooth_a", "Retinex: a piecewise-constant albedo leaves the shading to S_e (Eq. 10)", "albedo_shading_corr"),
    ("no_smooth_a", "Retinex: a better albedo (Eq. 10)", "albedo_si_mse"),
    ("no_smooth_s", "a smooth shading (Eq. 11)", "shading_si_mse"),
    ("no_smooth", "both smoothness priors (Eqs. 10, 11)", "albedo_si_mse"),
    ("no_matting", "the matte lets the face layers serve the face (Sec. 3.3)", "recon_face_psnr"),
    ("no_matting", "the matte lets the face layers serve the face (Sec. 3.3)", "normal_mean"),
    ("no_adv", "the adversarial loss: realistic, sharp faces (Eq. 7)", "recon_face_ssim"),
    ("no_pseudo_normal", "the morphable model's normals guide N_e (Eq. 8)", "normal_mean"),
    ("no_pseudo_light", "{light_target} guides the light (Eq. 9)", "light_shading_si_mse"),
    ("no_pseudo_light", "{light_target} guides the light where the face shows it (Eq. 9)", "sh_error_shown"),
    ("no_pseudo_light", "{light_target} guides the light, hidden SH directions too (claim 2: a guess)", "sh_error"),
)
# E_recon-L targets other than the paper's L-hat: an override (one ending in "=" stands for each of its values,
# setting_picks; {} in the words) -> its name in words (what no_pseudo_light takes away in a setting that names it),
# and the claims' paragraph on what it buys, read against the same setting without it (targets.light_target_lines)
LIGHT_TARGETS = {
    "loss.recon_L_target=sh_texture": (
        "the texture model's L-hat in L-hat's place",
        "What a better L-hat without truth buys: E_recon-L (Eq. 9) on L-hat fitted with the PCA texture model for the "
        "albedo in place of its constant (`loss.recon_L_target=sh_texture`, not the paper's; the lighting section's "
        '"PCA texture model fitted with the light" row), against the same setting with L-hat',
    ),
    "loss.recon_L_target=sh_pseudo_eroded": (
        "L-hat on M-hat eroded in L-hat's place",
        "What a more contrasty L-hat without truth buys: E_recon-L (Eq. 9) on L-hat fitted on M-hat eroded 1 px "
        "(`loss.recon_L_target=sh_pseudo_eroded`, not the paper's; the lighting section's row with M-hat eroded: "
        "its light shows the truth's contrast where L-hat's is flatter, by more magnitude with the same pattern), "
        "against the same setting with L-hat",
    ),
    "loss.recon_L_target=sh_network": (
        "a trained network's light in L-hat's place",
        "What a network's own light buys as the target: E_recon-L (Eq. 9) on the light a trained network draws from "
        "each image (`loss.recon_L_target=sh_network`, the shipped explicit model unless `loss.recon_L_network` names "
        "another; no truth, not the paper's; the lighting section's network rows: a better pattern than any L-hat "
        "without truth, less magnitude), against the same setting with L-hat",
    ),
    "loss.recon_L_target=sh_network_texture": (
        "a trained network's light and its texture-model refit in L-hat's place",
        "What a network's light with the texture model's refit buys as the target: E_recon-L (Eq. 9) on a trained "
        "network's own light averaged with L-hat fitted with the PCA texture model through the network's normals and "
        "uv (`loss.recon_L_target=sh_network_texture`, `loss.recon_L_network` the network; no truth, not the paper's; "
        "the lighting section's `network_NAME_texture` rows: nearer the truth on the face than either alone), against "
        "the same setting with L-hat",
    ),
    "loss.recon_L_scale=sh_pseudo": (
        "the target at L-hat's per-face scale",
        "Its shape or its scale: the same texture-model target scaled per face and channel to L-hat's mean shading "
        "over M-hat, its shape kept (`loss.recon_L_scale=sh_pseudo`, not the paper's), against the target at its own "
        "scale",
    ),
    "loss.recon_L_target=sh": (
        "the true light in L-hat's place",
        "What a perfect L-hat buys: E_recon-L (Eq. 9) on the scene's true light in L-hat's place "
        "(`loss.recon_L_target=sh`, an oracle, not the paper's; the lighting section says where L-hat's error comes "
        "from), against the same setting with L-hat",
    ),
    "loss.recon_L_oracle_mix=": (
        "L-hat moved {} of the way to the true light",
        "How good L-hat must be: E_recon-L (Eq. 9) on L-hat moved a share m of the way to the true light's shape "
        "(`loss.recon_L_oracle_mix=m`, L-hat's brightness and colour kept; an oracle dose, not the paper's), against "
        "the same setting with L-hat",
    ),
}


def setting_picks(where: str, key: str) -> list[str]:
    """The overrides of the setting ``where`` that ``key`` names: the override itself, or any value of a key ending
    in ``=`` (``loss.recon_L_oracle_mix=`` picks ``loss.recon_L_oracle_mix=0.5``); a network's target brings the
    network's name and the refit's share (``loss.recon_L_network=``, ``loss.recon_L_network_share=``) with it."""
    from disent.config import NETWORK_TARGETS

    picks = [t for t in where.split() if t == key or (key.endswith("=") and t.startswith(key))]
    if picks and key.partition("=")[2] in NETWORK_TARGETS:
        picks += [t for t in where.split() if t.startswith(("loss.recon_L_network=", "loss.recon_L_network_share="))]
    return picks


def light_target_name(where: str) -> str:
    """E_recon-L's target in the setting ``where`` in words (:data:`LIGHT_TARGETS`), else the paper's L-hat."""
    for key, (words, _) in LIGHT_TARGETS.items():
        if picks := setting_picks(where, key):
            return words.format(picks[0].split("=", 1)[1])
    return "L-hat"


CLAIM_METRICS = {  # metric -> its label in the claims' tables
    "shading_cast": "shading cast",
    "albedo_shading_corr": "corr(albedo, true shading)",
    "albedo_si_mse": "albedo si-MSE",
    "albedo_colour_si_mse": "albedo si-MSE, one scale for RGB",
    "shading_colour_si_mse": "shading si-MSE, one scale for RGB",
    "shading_albedo_tone_corr": "corr over faces (shading's tone, skin's tone)",
    "shading_si_mse": "shading si-MSE",
    "recon_face_psnr": "face PSNR",
    "recon_face_ssim": "face SSIM",
    "normal_mean": "normals (deg)",
    "light_shading_si_mse": "light on the face",
    "sh_error_shown": "shown SH error",
    "sh_error": "SH error, every direction",
}
HIGHER_IS_BETTER = ("recon_face_psnr", "recon_face_ssim")


def ablation_readings(runs: list[Run]) -> list[dict]:
    """Claim 4's readings: each ablation of the explicit model against the full model at the same budget and
    setting, on the metric where the paper says the ablated piece shows (:data:`ABLATION_CLAIMS`).  Each reading:
    ``where``, ``ablation``, ``reason``, ``key``, ``full`` and ``ablated`` (seed spreads), ``runs`` (the ablated
    runs), ``difference`` (the claims' rule) and ``gate`` (why its verdict is not read: the full model misses a
    default-run target there, or there is none; None where it is read)."""
    done = [r for r in runs if r.status == "ok" and r.eval and r.model == "explicit" and not r.ceiling]
    ablated: dict = {}  # (setting of the full model, ablation) -> runs
    for r in done:
        if len(r.ablations) == 1 and not is_recipe_run(r):
            ablated.setdefault((setting(r, drop=("ablation=",)), r.ablations[0]), []).append(r)
    full: dict = {}
    for r in done:
        if r.plain and not is_recipe_run(r):
            full.setdefault(setting(r), []).append(r)
    # an ablated run also stands against each full model whose setting differs from its own only in settings it
    # leaves idle (:func:`joins`: without BWS and the whitened L-hat, c does nothing)
    for (where, ablation), rs in list(ablated.items()):
        for label in full:
            if joined := [r for r in rs if joins(r, where, label)]:
                ablated.setdefault((label, ablation), []).extend(joined)
    readings = []
    for where in sorted({w for w, _ in ablated}):
        misses = budget_misses(full.get(where, []))
        gate = f"targets missed: {len(misses)} of {len(TARGETS)}" if misses else None
        gate = "no full model" if misses is None else gate
        for ablation, reason, key in ABLATION_CLAIMS:
            rs = ablated.get((where, ablation))
            if not rs:
                continue
            a, b = seed_spread(full.get(where, []), key), seed_spread(rs, key)
            if b is None or (a is None and full.get(where)):  # an arm's runs scored before the metric existed
                continue
            diff = verdict(a, b, "higher" if key in HIGHER_IS_BETTER else "lower")
            reason_here = reason.format(light_target=light_target_name(where))
            readings.append(
                dict(where=where, ablation=ablation, reason=reason_here, key=key, full=a, ablated=b, runs=rs)
                | dict(difference=diff, gate=gate)
            )
    return readings


def gated_verdict(reading: dict) -> str:
    """A claim-4 reading's verdict: its difference where the full model meets the targets, else not testable."""
    return f"not testable ({reading['gate']})" if reading["gate"] else reading["difference"]


def claim_ablations(rep: Report, runs: list[Run], glance: Glance | None = None) -> None:
    """Claim 4's table (:func:`ablation_readings`); a verdict only where the full model meets the targets (the
    differences at the ladder's rungs, and the gates, also put in ``glance``)."""
    glance = glance or Glance()
    columns = ("setting", "ablation", "what the paper says the piece does", "metric", "full model", "without it")
    head = table_head(*columns, "difference", "verdict")
    readings = ablation_readings(runs)
    rows = []
    for x in readings:
        plain = f"difference {x['difference'].replace('**', '')}" if x["gate"] else x["difference"]  # not a verdict
        glance.put("4", f"{x['ablation']}: {CLAIM_METRICS[x['key']]}", x["where"], "explicit", plain)
        if x["gate"] and (column := glance.column(x["where"], "explicit")):
            glance.gates[column] = x["gate"]
        rows.append(
            f"| `{x['where']}` | {x['ablation']} | {x['reason']} | {CLAIM_METRICS[x['key']]} | "
            f"{spread_text(x['full'], '.4g')} | {spread_text(x['ablated'], '.4g')} | {x['difference']} | "
            f"{gated_verdict(x)} |"
        )
    # a row is its setting, ablation and metric (the paper's reason is words, which may be reworded)
    if not rows:
        rep.note(
            "no finished ablation runs of the explicit model; run the suite (`ablations/suite.sh`) and point the "
            "report at its folders."
        )
        return
    rep.add(
        "Each ablation of `conf/ablation/` against the full explicit model of the same setting (budget), on the "
        "test metric where the paper's reason for the piece should show; *difference* applies the claims' rule "
        "(the full model better beyond both arms' seed spread: confirmed), *verdict* reads it only where the full "
        "model meets the default-run targets at that budget (`TARGETS`; the budget check under each ablation "
        "table; the glance section's *what holds the albedo back* says which of the shading's inputs keeps the "
        "albedo from its target, and *what a perfect L-hat buys* and *what a better L-hat without truth buys* how "
        "far the albedo gets with the true light, or L-hat fitted with a texture model, as E_recon-L's target).\n",
        *head,
        *rows,
        "",
    )
    failed = {}  # reason -> runs (disent.eval.metrics.normals_failure)
    for r in sorted({r.id: r for x in readings for r in x["runs"]}.values(), key=lambda r: r.id):
        if reason := normals_failure(r.eval):
            failed.setdefault(reason, []).append(r)
    for reason, caption in NORMAL_FAILURE_CAPTIONS.items():  # in the report's order
        if reason in failed:
            rep.add(caption, *(_normal_failure_line(r, reason) for r in failed[reason]), "")


NORMAL_FAILURE_CAPTIONS = {  # each reason of disent.eval.metrics.normals_failure
    "flat": f"Runs whose normals collapsed flat (their spread about each face's mean normal under {FLAT_SHARE:.0%} of "
    "the truth's; the albedo then takes the shading, and the reconstruction can stay good):\n",
    "frame": "Runs whose normals are farther from the truth than the dataset-mean map's but nearer once one rotation "
    "or mirror of the whole frame is forgiven: the face's shape learned in another frame, which an SH light of order "
    "2 turned with it renders alike, so the image cannot pin the frame; only the normals' supervision (Eq. 8) and "
    "the light's (Eq. 9) can (`disent.eval.metrics.aligned_normal_error`):\n",
    "astray": "Runs whose normals are farther from the truth than the dataset-mean map's without collapsing flat, "
    "and which no rotation or mirror of the frame brings nearer than it (–: scored before the frame check):\n",
}


def _normal_failure_line(r, reason: str) -> str:
    """One run of a :data:`NORMAL_FAILURE_CAPTIONS` list: its normals' spread and error, what one map of the frame
    leaves of the error where it was measured, and what the failure did to the albedo and the reconstruction."""
    aligned = r.value("normal_aligned_mean")
    if aligned is not None:
        frame = f"; {aligned:.1f} deg after {frame_map(r.eval)}"
    else:
        frame = "; after the best frame map –" if reason == "astray" else ""
    return (
        f"- {r.name}: spread {fmt_value(r.value('normal_spread'), '.1f')} deg "
        f"against {fmt_value(r.value('true_normal_spread'), '.1f')}, normals {r.value('normal_mean'):.1f} deg off "
        f"(the mean map's {fmt_value(r.value('trivial_normal_mean'), '.1f')}){frame}, "
        f"albedo {r.value('albedo_si_mse'):.4f} against the mean map's "
        f"{fmt_value(r.value('trivial_albedo_si_mse'), '.4f')}, face PSNR {r.value('recon_face_psnr'):.2f} dB"
    )


SKIN_METRICS = (  # (key, label, its floor's key or None): where each face's skin went (disent.eval.scoring.bws_stats)
    ("shading_albedo_tone_corr", "corr over faces: shading's tone, skin's tone", None),
    ("shading_albedo_brightness_corr", "the same, brightness", None),
    ("albedo_colour_si_mse", "albedo si-MSE, one scale for RGB", "trivial_albedo_colour_si_mse"),
    ("shading_colour_si_mse", "shading si-MSE, one scale for RGB", "trivial_shading_colour_si_mse"),
    ("albedo_si_mse", "albedo si-MSE, a scale per channel", "trivial_albedo_si_mse"),
    ("albedo_pattern_corr", "albedo pattern corr (higher: better)", None),
    ("albedo_ceiling_share", "albedo at its ceiling (share)", None),
)


def claim_skin(rep: Report, runs: list[Run]) -> None:
    """Where each face's skin went: BWS fixes the batch's mean shading colour, so a model can still put each face's
    skin tone and brightness in its shading (the degenerate split per face); one row per setting and model."""
    from disent.eval.scoring import ALBEDO_CEILING

    done = [r for r in runs if r.status == "ok" and r.eval and r.model in ("explicit", "implicit") and not r.ceiling]
    groups = by_setting_and_model(
        r for r in done if r.eval.get(SKIN_METRICS[0][0]) is not None and not is_recipe_run(r)
    )
    head = table_head("setting", "model", *(label for _, label, _ in SKIN_METRICS))
    rows = [
        f"| `{where}` | {model} | "
        + " | ".join(
            spread_text(seed_spread(rs, key), ".3g")
            + (f" (mean map {m['mean']:.3g})" if floor and (m := seed_spread(rs, floor)) else "")
            for key, _, floor in SKIN_METRICS
        )
        + " |"
        for (where, model), rs in sorted(groups.items())
    ]

    def truth(key):  # one test split, so the truth's value is the same in every run that has the key
        return next((v for rs in groups.values() for r in rs if (v := r.value(key)) is not None), None)

    tone, brightness, true_ceiling = (
        truth(f"true_{key}")
        for key in ("shading_albedo_tone_corr", "shading_albedo_brightness_corr", "albedo_ceiling_share")
    )
    if not rows:
        rep.note(
            "no run scored for where the skin goes; rescore finished runs with `python -m disent.eval.evaluate RUN`."
        )
        return
    rep.add(
        "Where each face's skin goes. BWS (Eq. 14) fixes the shading's mean colour over a batch, not over a face, "
        "and L-hat's constant albedo leaves each face's skin in the light that E_recon-L (Eq. 9) teaches "
        "(`loss.lhat_gray=true` takes each face's colour out of L-hat first; not the paper's). The first two columns "
        "correlate, over the test faces, the mean colour (chromaticity) and the mean brightness of the model's "
        "shading on each face with the true albedo's: 0 where the shading carries only the light"
        + (
            f" (the true shading: {tone:.2f} and {brightness:.2f})"
            if tone is not None and brightness is not None
            else ""
        )
        + ", towards 1 where it carries the skin. The si-MSEs with one scale shared by R, G and B forgive a face's "
        "brightness but not its colour: the albedo must carry the skin's colour, the shading the light's; the last two "
        "columns forgive both, what BWS decides: the si-MSE with a scale per channel (the targets' measure) and "
        "Pearson's correlation with the true albedo per image and channel, which forgives contrast too "
        "(`disent.eval.metrics.pattern_corr`; runs scored before it show –). The last column is the share of the "
        f"albedo's values (pixels and channels) at or above {ALBEDO_CEILING} of its sigmoid's 1"
        + (f" (the true albedo's: {true_ceiling:.3f})" if true_ceiling is not None else "")
        + ": where the split leaves the albedo near 1 (the shading takes the face's brightness: without BWS, or "
        "with a low c), the albedo is pinned at 1 over the skin and flat there, whatever the skin does "
        "(`disent.eval.scoring.ceiling_share`; runs scored before it show –). Test "
        "split, 256 images; mean ± std over seeds (`python -m disent.eval.evaluate RUN` scores a finished run).\n",
        *head,
        *rows,
        "",
    )
    plot_skin_albedos(rep, groups)


SKIN_FACES = 6  # test faces in the albedo-by-setting figure
SKIN_CAPTION = (
    "The albedo of one run per setting (explicit; the run's folder in parentheses) on the first "
    f"{SKIN_FACES} test faces, where its own matte is above 0.5, beside the true albedo"
)


def plot_skin_albedos(rep: Report, groups: dict) -> None:
    """The albedo of one explicit run per setting of the skin table (:func:`pick_runs`; the shipped model for a
    setting whose runs left no checkpoint but include the shipped one) on the same test faces, beside the input and
    the true albedo, each where its matte is above 0.5: how BWS and its c set the albedo's brightness and where it
    is pinned at 1.  Drawn where two settings or more have a model; else the committed figure is shown as an
    earlier build's."""
    from disent.eval.scoring import predict
    from disent.models.shipped import manifest

    shipped_run = str(manifest().get("explicit", {}).get("run", ""))
    sources = {}
    for (where, model), rs in sorted(groups.items()):
        if model != "explicit":
            continue
        if picked := pick_runs(rs, {r.variant for r in rs}):
            sources[where] = next(iter(picked.values()))
        elif shipped_run and any(r.id == run_ref(shipped_run) for r in rs):
            sources[where] = "explicit"  # the shipped weights
    if len(sources) < 2:  # the checkpoints are gone: the committed figure stays, said to be an earlier build's
        if (rep.fig / "skin_albedo.png").is_file():
            rep.add(
                f"{SKIN_CAPTION}; drawn by an earlier build from the checkpoints of one run per setting, which are "
                "gone (each column's title names its setting and run):\n"
            )
            rep.image(rep.fig / "skin_albedo.png", "albedo by setting")
        return
    try:
        models, batch = load_chosen(sources), test_batch(SKIN_FACES)
    except (ImportError, FileNotFoundError) as e:
        rep.note(f"cannot render the albedo by setting from checkpoints ({e}).")
        return
    columns = [("input", batch["image"]), ("true albedo", on_matte(batch, "albedo"))]
    for where, model in models.items():
        out = predict(model, batch["image"])
        shipped = " (shipped weights)" if isinstance(sources[where], str) else f" (#{sources[where].id})"
        columns.append((where + shipped, on_matte(out, "albedo")))
    plt = pyplot()
    fig, axes = plt.subplots(SKIN_FACES, len(columns), figsize=(1.15 * len(columns), 1.15 * SKIN_FACES + 0.9))
    for j, (name, t) in enumerate(columns):
        axes[0, j].set_title(wrapped(name, 22), fontsize=5)
        for i in range(SKIN_FACES):
            axes[i, j].imshow(to_array(t[i]), interpolation="nearest")
            axes[i, j].set_xticks([]), axes[i, j].set_yticks([])
    rep.add(f"{SKIN_CAPTION} ({len(sources)} settings):\n")
    rep.figure(fig, "skin_albedo.png", "albedo by setting")


def sec_ablation(rep: Report, runs: list[Run]) -> None:
    """One table per setting apart from the model and the ablation (the budget, ``+experiment=``, and any other
    override), so runs of different settings never share a mean."""
    kept = [r for r in runs if not is_recipe_run(r) and not r.ceiling]  # the ceiling has its own section
    groups, tables = group_by_setting(kept, drop=("ablation=",)), {}
    for name, rs in sorted(groups.items()) or [("(defaults)", [])]:
        tables[name] = _ablation.ablation_table(rs)
        rep.add(f"### {name if name == '(defaults)' else f'`{name}`'}\n")
        rep.add(_ablation.to_markdown(tables[name]))
        rep.add(budget_check([r for r in rs if r.variant == "explicit" and r.status == "ok"]))
    (rep.out / "ablation.json").write_text(
        json.dumps(tables if len(tables) > 1 else next(iter(tables.values()), {}), separators=(",", ":"))
    )
