"""Sections from what the evaluation tools measured (``reports/eval/``, ``reports/photos/``): SH variance,
stability where methods fail, methods on one plane, real photos."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from disent.eval import ablation as _ablation
from disent.eval.photos import steps_text
from disent.report.document import Report
from disent.report.tables import spread_text, table_head, verdict
from disent.storage import load_json


def sec_sh_variance(rep: Report, eval_dir: Path) -> None:
    res = load_json(eval_dir / "sh_variance.json")
    if not res:
        rep.note("`reports/eval/sh_variance.json`; run `python -m disent.eval.protocols`.")
        return
    rep.add(
        f"Protocol of the paper's supplement on the `{res.get('split', 'lightbank')}` split: for every light "
        "condition the variance of each SH coefficient across identities and poses, averaged over conditions "
        "and RGB. Paper: 0.36 (3DMM least squares) and 0.16 (network). *relative* divides by the estimator's "
        "mean squared coefficient (scale-free); *within share* is the within-condition variance over the variance "
        "across all images (1: the estimate ignores the light); SH error is relative, after per-image scale "
        "alignment (0 perfect, 1 uninformative). A constant estimate has zero variance, so read the variance "
        "beside the last two columns. `ls_oracle` (true normals and albedo) and `true` are checks. *shown* / "
        "*hidden*: the variance and the error split between the SH directions a face's shading shows and those it "
        "hides (`disent.eval.protocols.sh_variance_shown_hidden`; each estimate scaled to the truth in shading, a "
        "share of the true light's squared norm); `mean_light` is the training split's mean light, the trivial "
        "baseline (its only spread is its per-image scale).\n",
        *table_head(
            "estimator",
            "variance",
            "relative",
            "within share",
            "SH error",
            "variance shown / hidden",
            "SH error shown / hidden",
            "conditions",
            "images",
        ),
    )
    for k, v in res["estimators"].items():
        split = (
            (f"{v[f'{key}_shown']:.3g} / {v[f'{key}_hidden']:.3g}" for key in ("variance", "sh_error"))
            if "variance_shown" in v
            else ("–", "–")  # a row measured before the split
        )
        rep.add(
            f"| {k} | {v['mean']:.4g} | {v['relative']:.4g} | {v.get('within_share', float('nan')):.3g} | "
            f"{v['sh_error']:.4g} | {' | '.join(split)} | {v['n_conditions']} | {v['n_images']} |"
        )
    rep.add("")
    published_figure(rep, eval_dir / "sh_variance.png", "SH variance per coefficient")
    from disent.eval.protocols import CHECKS, FITTED

    if not any(k not in (*FITTED, *CHECKS) for k in res["estimators"]):
        rep.note(
            "no trained model's Z_L in the SH-variance table (no finished explicit/implicit run when it was computed)."
        )


def published_figure(rep: Report, path: Path, alt: str) -> None:
    """Show the figure a tool published beside its JSON (the report does not draw a second copy)."""
    if path.is_file():
        rep.image(path, alt)
    else:
        rep.note(f"`{rep.link(path)}` is missing; publish the tool folder that wrote the JSON beside it.")


def _stability_conditioning(rep: Report, cond: dict | None, eval_dir: Path) -> None:
    from disent.eval import stability as st

    rep.add("### L-hat conditioning against yaw and mask size\n")
    if cond:
        rep.add(
            f"Median over {cond['yaw']['n']} test faces turned to each yaw (pitch = roll = 0), and over "
            f"{cond['mask']['n']} test faces whose mask is shrunk towards its centre. `ls_oracle_noisy` fits with "
            f"true normals and albedo on the image plus Gaussian noise (sigma {st.ORACLE_NOISE}): its error is "
            "conditioning alone. Where the condition number passes the fit's `max_cond` (1e7) the fit is "
            "ridge-regularised (`disent.render.fit_sh`).\n"
        )

        def at(v, unit=""):
            return "never in the range" if v is None else f"**{v}{unit}**"

        f = cond["yaw"]["blowup_factor"]
        for est in st.LS_ESTIMATORS:
            y, m = cond["yaw"], cond["mask"]
            rep.add(
                f"- `{est}`: condition number {f:g}x its frontal value at yaw {at(y.get(est + '_blowup_yaw'), '°')}, "
                f"SH error {f:g}x at yaw {at(y.get(est + '_blowup_yaw_error'), '°')}; against the full mask, "
                f"condition {f:g}x at mask share {at(m.get(est + '_blowup_fraction'))}, "
                f"SH error {f:g}x at {at(m.get(est + '_blowup_fraction_error'))}."
            )
        for res, key, unit in ((cond["yaw"], "yaw", "°"), (cond["mask"], "fraction", "")):
            rep.add(
                "",
                *table_head(key, "face pixels", *(c for e in st.LS_ESTIMATORS for c in (f"cond {e}", f"SH err {e}"))),
            )
            for r in res["rows"]:
                if "error" in r:
                    rep.add(
                        f"| {r[key]}{unit} | – | " + " | ".join("–" for _ in range(2 * len(st.LS_ESTIMATORS))) + " |"
                    )
                    continue
                rep.add(
                    f"| {r[key]}{unit} | {r['face_pixels']:.0f} | "
                    + " | ".join(
                        f"{r[e + '_cond']['median']:.3g} | {r[e + '_sh_error']['median']:.3g}"
                        for e in st.LS_ESTIMATORS
                        if e + "_cond" in r
                    )
                    + " |"
                )
        bad = [r for r in cond["yaw"]["rows"] if "error" in r]
        if bad:
            rep.add(f"- yaws the generator refused: {', '.join(str(r['yaw']) for r in bad)}")
        rep.add("")
        published_figure(rep, eval_dir / "conditioning.png", "conditioning")
    else:
        rep.note("`reports/eval/conditioning.json`; run `python -m disent.eval.stability conditioning`.")


BREAK_FACTOR = 1.5  # an estimator breaks at the first severity whose error is this many times its clean error


def _stability_ood(rep: Report, res: dict) -> None:
    """Where each estimator breaks: per effect, the first severity whose error passes ``BREAK_FACTOR`` x its
    error on clean images, for the normals and the light."""
    sev = res["severities"]
    rep.add(
        f"Where each estimator breaks: the first severity at which its error passes {BREAK_FACTOR:g}x its error on "
        f"clean images ({res['n']} test images a point; `–`: not within the range). `light` turns the light "
        "out of the training prior (severity x 180 deg about the camera's x axis); `yaw` turns every face to "
        "severity x 90 deg (the prior spans +-45 deg); `scale` draws every face at (1 - severity / 2) times its "
        "scale (the prior spans +-10 %), the framing real photos' crops and heads vary in.\n",
        *table_head(
            "effect", "estimator", "normal error: clean -> worst", "breaks at", "SH error: clean -> worst", "breaks at"
        ),
    )

    from disent.eval.stability import first_past

    def breaks(values):
        if not values or not values[0] > 0:
            return "–", "–"
        at = first_past(sev, values, values[0], BREAK_FACTOR)
        return f"{values[0]:.3g} -> {max(values):.3g}", "–" if at is None else f"{at:g}"

    for effect, curves in res["effects"].items():
        for est, c in curves.items():
            n_range, n_at = breaks(c.get("normal_mean"))
            sh_range, sh_at = breaks(c.get("sh_error"))
            if (n_range, sh_range) != ("–", "–"):  # an estimator of neither (the baseline) has no row
                rep.add(f"| {effect} | {est} | {n_range} | {n_at} | {sh_range} | {sh_at} |")
    rep.add("")
    uv = [(e, est, c) for e, curves in res["effects"].items() for est, c in curves.items() if c.get("uv_error")]
    if uv:  # why the implicit model's normals break: its UV map, or its UV-space normals
        rep.add(
            "Why a UV model's normals break: its UV map against the true one (*uv error*, UV units) and its "
            "UV-space normals looked up at the true UV (`disent.eval.scoring.uv_metrics`), each read at the "
            f"severity where the normals break: a step whose error has passed {BREAK_FACTOR:g}x its clean value "
            "there has failed.\n",
            *table_head(
                "effect", "estimator", "uv error: clean -> worst", "normals at the true UV (deg)", "normals break in"
            ),
        )
        for effect, est, c in uv:
            at = first_past(sev, c["normal_mean"], c["normal_mean"][0], BREAK_FACTOR)
            looked_up = c["normal_at_true_uv_mean"]
            if at is None:
                where = "–"
            else:
                i = sev.index(at)
                failed = [
                    step
                    for step, curve in (("the UV map", c["uv_error"]), ("the UV-space normals", looked_up))
                    if curve[i] >= BREAK_FACTOR * curve[0]
                ]
                where = " and ".join(failed) or "neither step alone"
                where += (
                    f" (at {at:g}: uv error {c['uv_error'][i]:.3g}, normals {c['normal_mean'][i]:.3g} deg, "
                    f"{looked_up[i]:.3g} at the true UV)"
                )
            rep.add(
                f"| {effect} | {est} | {c['uv_error'][0]:.3g} -> {max(c['uv_error']):.3g} | "
                f"{looked_up[0]:.3g} -> {max(looked_up):.3g} | {where} |"
            )
        rep.add("")


def _stability_bws(rep: Report, res: dict) -> None:
    """The BWS table: shading cast, albedo absorbing shading and where the skin went, per arm and batch size."""
    from disent.eval.stability import BWS_ARMS, bws_arm

    keys = ("true_shading_albedo_tone_corr", "true_shading_albedo_brightness_corr")
    first = res["rows"][0] if res["rows"] else {}
    truth = (
        f" (the true shading: {first[keys[0]]:.2f} and {first[keys[1]]:.2f})" if all(k in first for k in keys) else ""
    )
    floor = first.get("trivial_normal_mean")
    mean_map = f" (the dataset-mean normal map: {floor:.2f} deg)" if floor is not None else ""
    rep.add(
        f"Mean ± std over seeds on {res['n']} test images. BWS pulls each channel's shading mean to 0.75; "
        "*cast* is the spread of the three channel means; *corr(albedo, true shading)* is the correlation of "
        "the estimated albedo with the true shading (0: albedo free of shading). A run saw *steps* x *batch* training "
        "images, so where the steps are fixed a small batch also trains less: *normals* (test split) says "
        f"whether a run learned its geometry at all{mean_map}; rows whose *steps* x *batch* equal the largest "
        "batch's images trained every batch size on the same images (`IMAGES=N ablations/bws.sh`; dashed in the "
        "figure), which separates a small batch's per-face whitening from its shorter training. With BWS on, "
        "E_recon-L's target "
        "L-hat is itself scaled so that its shading has batch mean c (`loss.lhat_white`), a second "
        "whitening; `+ablation=no_bws` turns both off (the paper's ablation: the rows marked *raw L-hat target*), "
        "the rows marked *L-hat target still white* turn off only the BWS term. The two tone and brightness columns "
        "say where each face's skin went (the skin table of claim 4): the correlation over faces of the shading's "
        "mean tone and brightness with the true "
        f"albedo's{truth}; – where the study predates them.\n",
        *table_head(
            "arm",
            "batch",
            "steps",
            "seeds",
            "shading mean r, g, b",
            "cast",
            "corr(albedo, true shading)",
            "corr over faces: shading's tone, skin's tone",
            "the same, brightness",
            "normals (deg)",
        ),
    )

    def ms(vals):  # the table has a seeds column
        return spread_text(_ablation.mean_std(vals), ".3f", count=False)

    groups = {}
    for r in res["rows"]:
        groups.setdefault((bws_arm(r), r["batch_size"], r.get("steps")), []).append(r)
    order = list(BWS_ARMS)  # the figure's legend order, then by batch size and steps
    for (key, bs, steps), rs in sorted(
        groups.items(), key=lambda kv: (order.index(kv[0][0]), kv[0][1] or 0, kv[0][2] or 0)
    ):
        arm = BWS_ARMS[key]
        rgb = ", ".join(f"{float(np.mean([r['shading_mean_rgb'][c] for r in rs])):.2f}" for c in range(3))
        steps = "–" if steps is None else steps
        skin = " | ".join(
            ms([r[k] for r in rs]) if all(r.get(k) is not None for r in rs) else "–"
            for k in ("shading_albedo_tone_corr", "shading_albedo_brightness_corr", "normal_mean")
        )
        rep.add(
            f"| {arm} | {bs} | {steps} | {len(rs)} | {rgb} | {ms([r['shading_cast'] for r in rs])} | "
            f"{ms([r['albedo_shading_corr'] for r in rs])} | {skin} |"
        )
    rep.add("")
    _bws_same_images(rep, res["rows"])
    if len({r["batch_size"] for r in res["rows"]}) < 2:
        rep.note(
            "the BWS batch-size sweep (one batch size only in these runs); run the `multirun/bws` sweeps of "
            "`ablations/README.md` for the curve against batch size."
        )


def _bws_same_images(rep: Report, rows: list) -> None:
    """The shading's tone against the skin's per batch size on the fixed-images budget, with BWS and without it."""
    from disent.eval.stability import BWS_ARMS, bws_arm, bws_budgets

    budgets = bws_budgets(rows)
    if len(budgets) < 2 or not all("shading_albedo_tone_corr" in r for r in rows):
        return
    label, same_images = budgets[1]
    arms = {BWS_ARMS[key]: key for key in ((True, True), (False, False))}
    parts = []
    for bs in sorted({r["batch_size"] for r in rows if same_images(r)}):
        tones = {
            arm: [
                r["shading_albedo_tone_corr"]
                for r in rows
                if same_images(r) and r["batch_size"] == bs and bws_arm(r) == key
            ]
            for arm, key in arms.items()
        }
        if all(tones.values()):
            spreads = [_ablation.mean_std(v) for v in tones.values()]
            parts.append(
                f"batch {bs}: "
                + ", ".join(f"{spread_text(st)} {arm}" for st, arm in zip(spreads, tones))
                + f", lower with BWS: {verdict(*spreads, 'lower')}"
            )
    if parts:
        rep.add(
            "BWS fixes the mean shading of a batch: at batch 1 that is each face's own mean, which should keep the "
            "skin's tone out of each face's shading, while a larger batch fixes only the batch's mean. On the same "
            f"{label} at every batch size, the correlation over faces of the shading's tone with the skin's (the "
            f"true shading's: {rows[0].get('true_shading_albedo_tone_corr', float('nan')):.2f}), mean ± std over "
            "seeds: " + "; ".join(parts) + ".\n"
        )


def _stability_training(rep: Report, res: dict) -> None:
    """The training-stability table: outcome rates per model, adversarial term and learning rate."""
    from disent.eval import stability as st

    if len({r["lr"] for r in res["rows"]}) < 2:
        rep.note(
            "the learning-rate sweep (one learning rate only in these runs); run the `multirun/lr` sweeps of "
            "`ablations/README.md` for NaN / divergence rate against learning rate."
        )
    rep.add(
        f"Outcomes (`disent.eval.stability.outcome`): *NaN*, a loss term became non-finite (training stops, "
        "`status.json` says so); *diverged*, the last logged total loss above 2x the first; *exploded*, a "
        f"logged total loss above {res.get('spike', st.SPIKE):g}x the run's smallest "
        "(a blow-up before the first "
        "log escapes the previous rule); *collapsed*, the checkpoint's reconstructions vary across "
        f"{res.get('n', 'the')} test images by less than {st.COLLAPSE:g}x the images' own spread (the output "
        "ignores the input). Loss ratios, test recon MSE, normal error and input dependence are medians "
        "over the group's seeds"
        + (f"; the mean test image scores recon MSE {res['reference_mse']:.4f}" if res.get("reference_mse") else "")
        + ".\n",
        *table_head(
            "model",
            "adversarial",
            "lr",
            "runs",
            "NaN",
            "diverged",
            "exploded",
            "collapsed",
            "largest / smallest loss",
            "last / first loss",
            "test recon MSE",
            "normal err (deg)",
            "input dependence",
        ),
    )

    def g(v, fmt=".3g"):
        return "–" if v is None else format(v, fmt)

    for r in res["rows"]:
        rep.add(
            f"| {r['model']} | {r['adversarial']} | {r['lr']} | {r['runs']} | "
            + " | ".join(f"{r.get(f + '_rate', 0.0):.2f}" for f in st.FAILURES)
            + f" | {g(r.get('loss_spread'))} | {g(r.get('loss_ratio'))} | {g(r.get('recon_mse'), '.4f')} | "
            f"{g(r.get('normal_mean'), '.1f')} | {g(r.get('input_dependence'))} |"
        )
    rep.add("")


def sec_stability(rep: Report, eval_dir: Path) -> None:
    from disent.eval import stability as st

    _stability_conditioning(rep, load_json(eval_dir / "conditioning.json"), eval_dir)
    for name, title, table in (
        ("ood", "Out of distribution: error against severity", _stability_ood),
        ("bws", "Without BWS: shading cast and albedo absorbing shading", _stability_bws),
        ("training", "Training stability: NaN and divergence rate", _stability_training),
    ):
        rep.add(f"### {title}\n")
        res = load_json(eval_dir / f"{name}.json")
        if not res or (isinstance(res.get("rows"), list) and not res["rows"]):
            rep.note(
                f"no data for `{name}`; run `python -m disent.eval.stability {name}` after the runs it needs "
                "(see `ablations/README.md`)."
            )
            continue
        published_figure(rep, eval_dir / f"{name}.png", name)
        if "budget" in res:
            rep.add(f"_Budget of these runs (their configs): {st.budget_text(res['budget'])}._\n")
        if table is not None:
            table(rep, res)


def load_text(load: dict) -> str:
    """One sentence on the machine's load around a timing run: ``{before, after, cpus}`` 1-minute averages."""
    text = f" Load average {load['before']:.1f} at the start and {load['after']:.1f} at the end on {load['cpus']} CPUs"
    if max(load["before"], load["after"]) > load["cpus"]:
        return text + (
            ": above the CPU count, other work shared the cores and every time is inflated alike, so compare "
            "the times with each other, not with another run's."
        )
    return text + ": at most the CPU count, no other work competed for the cores."


def sec_methods(rep: Report, eval_dir: Path) -> None:
    """Every estimator's time per image against its accuracy, from ``reports/eval/methods.json``."""
    from disent.eval.methods import PANELS

    res = load_json(eval_dir / "methods.json")
    if not res:
        rep.note("`reports/eval/methods.json`; run `python -m disent.eval.methods`, then publish its folder.")
        return
    rep.add(
        f"Regenerate: `python -m disent.eval.methods --n {res['n']}`, then `python -m disent.report --publish "
        f"FOLDER`. The first {res['n']} SynthFaces test images, every estimator timed in the same run on one "
        "thread (a network at that batch); metrics on the pixels the networks are scored on. The coarse fit is "
        "the simulated pseudo ground truth: it starts from the scene's parameters, so its time is a lower bound "
        "for a real fit; *landmarks + fit* is the real pipeline (dlib and the face model) on the renders, scored "
        "where dlib found the face. A *network* row is that model's shipped weights (one run; the headline and "
        "claims pages give every seed)."
        + (f" Machine: {res['machine']}." if res.get("machine") else "")
        + (load_text(res["load"]) if res.get("load") else "")
        + "\n",
        *table_head("estimator", "ms / image", "images", *(label for _, label, _ in PANELS)),
    )
    for name, r in res["rows"].items():
        t = "constant" if r.get("constant") else f"{1e3 * r['seconds_per_image']:.3g}"
        extra = f" ({100 * r['detection_rate']:.0f} % detected)" if "detection_rate" in r else ""
        cells = " | ".join(f"{r[k]:.3g}" if k in r else "–" for k, _, _ in PANELS)
        rep.add(f"| {name}{extra} | {t} | {r['images']} | {cells} |")
    rep.add(
        "",
        "Each estimator's time per image against each accuracy; the points no other beats on both axes, the Pareto "
        "front, are outlined (`disent.eval.methods.pareto`).\n",
    )
    published_figure(rep, eval_dir / "methods.png", "methods on one plane")


def sec_photos(rep: Report, out: Path) -> None:
    """The shipped models on real photos: the domain gap against the pseudo ground truth, beside the training set's
    constants, and the decompositions (``reports/photos/``, published from ``python -m disent.eval.photos``)."""

    folder = out / "photos"
    gaps = []
    for path in sorted(folder.glob("domain_gap_*.json")):
        g = load_json(path)
        if g:
            gaps.append({"tag": path.stem.removeprefix("domain_gap_"), **g})
    if not gaps:
        rep.note(
            "`reports/photos/domain_gap_*.json`; run `python -m disent.eval.photos --run explicit implicit` and "
            "publish its folder."
        )
        return
    rep.add(
        "Regenerate: `python -m disent.eval.photos --run explicit implicit --workers 1`, then `python -m "
        f"disent.report --publish FOLDER`. The bundled photos through the pseudo-GT pipeline (dlib landmarks and the "
        f"face model; its accuracy on renders: `photos/pseudo_gt.json`). {GAP_TEXT}\n",
        *gap_table(gaps),
        "",
        *(anatomy := anatomy_table(gaps)),
        *([""] if anatomy else []),
    )
    for g in gaps:
        for name, alt in (
            (f"decomposition_{g['tag']}", "decomposition of photos"),
            (f"decomposition_{g['tag']}_colour_matched", "decomposition of colour-matched photos"),  # the anatomy's
            (f"relight_{g['tag']}", "relighting of photos"),
            (f"relight_{g['tag']}_colour_matched", "relighting of colour-matched photos"),
        ):
            if (folder / f"{name}.png").is_file():
                rep.image(folder / f"{name}.png", f"{alt}, {g['tag']}")


# ----------------------------------------------------------------------------- the photo study's tables
def gap_table(gaps: list[dict]) -> list[str]:
    """The domain-gap table (Markdown lines) of ``gaps`` (:func:`apply_run`'s results, each with its ``tag``):
    each model on the photos and on SynthFaces, its normals and light beside the training set's constants."""

    def read(net, const, d):  # the network's number, then the constant's, marked where the network is no better
        return f"{net:.{d}f}" if net < const else f"{net:.{d}f} (not better)"

    lines = [
        *table_head(
            "model (tag)",
            "training",
            "domain",
            "n",
            "recon PSNR (dB)",
            "normal vs normal_pseudo (deg)",
            "mean map (deg)",
            "SH vs sh_pseudo",
            "mean L-hat",
            "light on the face vs L-hat's",
            "mean L-hat",
            "matte IoU with mask_pseudo",
        )
    ]
    for g in gaps:
        t = g["training"]
        photos = "photos" if g.get("photo_pixels") == "linear" else "photos, sRGB codes (written before decoding)"
        for dom, label in (("photos", photos), ("synthfaces_test", "SynthFaces test")):
            m = g[dom]
            cells = []
            for key, d in (("normal_vs_pseudo_deg", 2), ("sh_vs_pseudo_mse", 3), ("light_vs_pseudo_shading_si_mse", 4)):
                const = m.get("trivial_" + key)
                net = "–" if key not in m else f"{m[key]:.{d}f}" if const is None else read(m[key], const, d)
                cells += [net, "–" if const is None else f"{const:.{d}f}"]
            iou = f"{m['matte_iou_mask_pseudo']:.3f}" if "matte_iou_mask_pseudo" in m else "–"
            lines.append(
                f"| {g['model']} ({g['tag']}) | {steps_text(t)}, {t.get('train_size')} training images | {label} | "
                f"{m['n']} | {m['recon_psnr']:.2f} | "
                f"{' | '.join(cells)} | {iou} |"
            )
    return lines


def anatomy_table(gaps: list[dict]) -> list[str]:
    """What the gap is made of (Markdown lines; results with an ``anatomy``): each model's normals against
    ``normal_pseudo`` on SynthFaces in colour and in gray (LFW's photos are gray), on the photos as stored
    (sRGB-encoded: what a model reads without the decoding), on the photos with their crops magnified about the
    centre (:data:`ZOOMS`; 1 is the template's framing, which matches SynthFaces'), and on the photos
    colour-matched to SynthFaces (:func:`colour_matched`)."""
    gaps = [g for g in gaps if "normal_vs_pseudo_deg" in g.get("anatomy", {}).get("synthfaces_test_grayscale", {})]
    if not gaps:
        return []

    def deg(m):
        return m["normal_vs_pseudo_deg"]

    zooms = list(gaps[0]["anatomy"]["photos_zoom"])
    lines = [
        "Normals against `normal_pseudo` (deg) where the domains differ one way at a time: SynthFaces' test faces "
        "in colour and turned gray, the photos as stored (sRGB-encoded, not decoded to linear radiance), the photos' "
        "crops magnified about their centre (x1: the template's framing, the SynthFaces faces' mean size), and the "
        "photos with their face's colour matched to SynthFaces' "
        "(`colour_matched`: per channel, the training faces' mean and std inside `mask_pseudo`).\n",
        *table_head(
            "model (tag)",
            "SynthFaces",
            "SynthFaces gray",
            "photos as stored (sRGB)",
            *(f"photos x{z}" for z in zooms),
            "photos colour-matched",
            "mean map",
        ),
    ]
    for g in gaps:
        a = g["anatomy"]
        cells = [
            g["synthfaces_test"],
            a["synthfaces_test_grayscale"],
            a.get("photos_srgb"),  # results written before the photos were decoded have none
            *(a["photos_zoom"][z] for z in zooms),
        ]
        matched = a.get("photos_colour_matched")
        degrees = " | ".join("–" if m is None else f"{deg(m):.2f}" for m in cells)
        tail = "– | –" if matched is None else f"{deg(matched):.2f} | {matched['trivial_normal_vs_pseudo_deg']:.2f}"
        lines.append(f"| {g['model']} ({g['tag']}) | {degrees} | {tail} |")
    lines.append("")
    for g in gaps:  # how much of the gap (photos at x1 over SynthFaces) each difference accounts for
        a = g["anatomy"]
        gap = deg(g["photos"]) - deg(g["synthfaces_test"])
        gray = deg(a["synthfaces_test_grayscale"]) - deg(g["synthfaces_test"])
        best = min(zooms, key=lambda z: deg(a["photos_zoom"][z]))
        reframed = round(deg(g["photos"]) - deg(a["photos_zoom"][best]), 2) + 0.0  # no "-0.00"
        small = max(gray, reframed) < 0.25 * gap
        colour = deg(g["photos"]) - deg(a["photos_colour_matched"]) if "photos_colour_matched" in a else None
        decoded = deg(a["photos_srgb"]) - deg(g["photos"]) if "photos_srgb" in a else None
        lines.append(
            f"- {g['tag']}: the gap is {gap:.2f} deg"
            + ("" if decoded is None else f" ({decoded:.2f} less than on the photos as stored, sRGB-encoded)")
            + f"; gray faces account for {gray:.2f} of it, and the best framing (x{best}) for {reframed:.2f}"
            + ("" if colour is None else f"; matching the face's colour statistics closes {colour:.2f}")
            + (": most of the gap lies in the faces' appearance." if small else ".")
        )
    return lines


GAP_TEXT = (
    "The photos' pixels are decoded from sRGB to linear radiance, SynthFaces' space, before the pseudo-GT fit and "
    "the models read them. Every number is against the *pseudo* ground truth, the same landmark-fit rendering on "
    "both domains; *light on the face*: the light's shading through `normal_pseudo` against L-hat's "
    "(scale-invariant MSE inside `mask_pseudo`), which leaves out the SH directions a face hides; reference: "
    "as many SynthFaces test faces. *Mean map* and *mean L-hat*: the training set's mean normal map and mean L-hat "
    "scored the same way; a network reads a domain's faces only where it beats them (else marked *not better*)."
)
