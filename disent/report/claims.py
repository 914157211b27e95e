"""At a glance and the paper's claims, measured (claims 1, 2, 3 and 5; claim 4 is :mod:`disent.report.ablations`)."""

from __future__ import annotations

from pathlib import Path

from disent.edit.measure import DRAWN_READINGS, OFF_TARGET_READINGS
from disent.eval import ablation as _ablation
from disent.eval.scoring import MATTE_EDGE
from disent.eval.trivial import TEMPLATE_KEYS
from disent.images import pyplot
from disent.regions import FACE_THRESHOLD
from disent.report.ablations import (
    LIGHT_TARGETS,
    TARGETS,
    albedo_share,
    budget_misses,
    claim_ablations,
    claim_skin,
    setting_picks,
)
from disent.report.document import Report, unoverlap
from disent.report.tables import (
    EDIT_WORKS,
    MIN_SEEDS,
    Glance,
    by_setting_and_model,
    fmt_value,
    ladder_runs,
    on_the_ladder,
    seed_spread,
    seeds_cell,
    shipped_run,
    spread_text,
    table_head,
    verdict,
    verdict_word,
)
from disent.report.training import uv_glance_lines
from disent.runs import Run, composed_config, group_by_setting, measured_setting, run_ref, setting, typed
from disent.storage import load_json

# The trainable-models targets by rung: the default rung's absolute ones (TARGETS), the long rung's normals 15 %
# better than the pseudo-GT they were supervised by (the paper's "beyond the morphable model" claim, with a margin)
LONG_NORMALS_SHARE_OF_PSEUDO = 0.85
TEMPLATE_LABELS = ("albedo si-MSE", "one scale for RGB", "one scale per channel for all faces")  # of TEMPLATE_KEYS


def rung_of(where: str) -> str | None:
    """The budget-ladder rung a setting trains at ("default", "long"), or None where it sets a budget of its own."""
    tokens = where.split()
    own_budget = ("train.max_steps=", "train.epochs=", "train.batch_size=", "data.train_size=", "+experiment=")
    if any(t.startswith(own_budget) and t != "+experiment=long" for t in tokens):
        return None
    return "long" if "+experiment=long" in tokens else "default"


def rung_misses(rung: str | None, runs: list[Run]) -> list[str] | None:
    """The targets of ``rung`` that ``runs`` (one setting and model) miss on their mean over seeds: the default
    rung's (:func:`disent.report.ablations.budget_misses`), and at the long rung also normals
    :data:`LONG_NORMALS_SHARE_OF_PSEUDO` of the pseudo-GT's error; empty where they meet them all, None where
    there are no targets (no rung, no finished run)."""
    misses = budget_misses(runs) if rung else None
    if misses is None or rung == "default":
        return misses
    normal, pseudo = seed_spread(runs, "normal_mean"), seed_spread(runs, "pseudo_normal_mean")
    goal = LONG_NORMALS_SHARE_OF_PSEUDO * pseudo["mean"] if pseudo else None
    own = [f"normals (<= {goal:.2f})"] if goal is None or normal["mean"] > goal else []
    # the ablations' budget check holds every budget to the default rung's targets
    return own + [f"default rung's {m}" for m in misses]


def without_truth_lines(runs: list[Run]) -> list[str]:
    """The settings off the ladder whose runs meet every target of their rung (:func:`rung_misses`) without
    SynthFaces' truth (the paper's model with another setting: no ablation, no ceiling term, no oracle light), with
    their numbers; one sentence where none does; nothing without such runs."""
    off = [r for r in runs if r.status == "ok" and r.eval and r.plain and not r.light_oracle and not on_the_ladder(r)]
    groups = {k: rs for k, rs in by_setting_and_model(off).items() if k[1] != "baseline"}
    rungs = {k: rung_of(k[0]) for k in groups}
    misses = {k: rung_misses(rungs[k], rs) for k, rs in groups.items()}
    scored = [k for k, m in misses.items() if m is not None]
    if not scored:
        return []
    meets = [
        f"- `{where}` ({model}, {rungs[where, model]} rung): normals {spread_text(seed_spread(rs, 'normal_mean'))} "
        f"deg, face PSNR {spread_text(seed_spread(rs, 'recon_face_psnr'))} dB, albedo "
        f"{spread_text(seed_spread(rs, 'albedo_si_mse'), '.4f')}, {albedo_share(rs):.3f} of the mean map's."
        for (where, model), rs in sorted(groups.items())
        if misses[where, model] == []
    ]
    intro = (
        f"Off the ladder: of the {len(scored)} other setting(s) and model(s) trained at a rung without the truth "
        "(no ablation, no ceiling term, no oracle light; each changes the paper's objective, so none is the paper's "
        "model), "
    )
    if not meets:
        return [intro + "none meets every target of its rung.\n"]
    return [intro + f"{len(meets)} meet(s) every target of its rung, on the mean over seeds:\n", *meets, ""]


def template_section(rep: Report, groups: dict) -> None:
    """The albedo against the stronger floor, the placed mean texture, for each setting and model of ``groups``."""
    template_rows = [
        f"| `{where}` | {model} | "
        + " | ".join(
            f"{spread_text(seed_spread(rs, key), '.4f')} / {seed_spread(rs, f'template_{key}')['mean']:.4f} / "
            f"{seed_spread(rs, f'trivial_{key}')['mean']:.4f}"
            for key in TEMPLATE_KEYS
        )
        + " |"
        for (where, model), rs in sorted(groups.items())
        if all(seed_spread(rs, f"template_{key}") and seed_spread(rs, key) for key in TEMPLATE_KEYS)
    ]
    head = table_head(
        "setting", "model", *(f"{label}: network / placed mean texture / mean map" for label in TEMPLATE_LABELS)
    )
    if template_rows:
        rep.add(
            "A stronger floor for the albedo: the *placed mean texture*, the mean train albedo in UV space put on each "
            "test face through its true uv (`disent.eval.trivial.template_albedo`). It knows where the face's eyes, "
            "brows and lips are and nothing of whose face it is, so an albedo that beats the mean map but not this "
            "floor has learned where the face is, not what it looks like. Three scorings: a scale per image and "
            "channel (the targets' measure), one scale per image for R, G and B (the skin's colour must be in the "
            "albedo), one scale per channel for the whole test set (each face's brightness must be too).\n",
            *head,
            *template_rows,
            "",
        )


def sec_targets(rep: Report, runs: list[Run]) -> None:
    """At a glance: each model of the budget ladder against its rung's targets and its floors (mean ± std over seeds);
    a layer is learned only where it beats its floor, the dataset-mean map."""
    groups = by_setting_and_model(ladder_runs(runs))
    head = table_head(
        "setting",
        "model",
        "seeds",
        "normals (deg)",
        "mean map / pseudo-GT (deg)",
        "face PSNR (dB)",
        "albedo / mean map's",
        "targets missed",
    )
    rows = []
    for (where, model), rs in sorted(groups.items()):
        normal, pseudo, floor = (
            seed_spread(rs, k) for k in ("normal_mean", "pseudo_normal_mean", "trivial_normal_mean")
        )
        psnr, share = seed_spread(rs, "recon_face_psnr"), albedo_share(rs)
        misses = []
        if model != "baseline":
            misses = rung_misses(rung_of(where), rs)
            misses = ["(no targets at this setting)"] if misses is None else misses
        rows.append(
            f"| `{where}` | {model} | {seeds_cell(rs)} | {spread_text(normal)} | "
            f"{fmt_value(normal and floor and floor['mean'], '.2f')} / {fmt_value(pseudo and pseudo['mean'], '.2f')} | "
            f"{spread_text(psnr)} | "
            f"{fmt_value(share, '.2f')} | {'; '.join(misses) if misses else ('none' if model != 'baseline' else '–')} |"
        )
    if not rows:
        rep.note("no finished runs of the budget ladder (`python -m disent model=MODEL seed=N`).")
        return
    rep.add(
        "The budget ladder's runs against the targets of a trainable recipe: at the default rung normals <= "
        f"{TARGETS['normal_mean']} deg, face PSNR >= {TARGETS['recon_face_psnr']} dB and albedo scale-invariant "
        f"error <= {TARGETS['albedo_share_of_trivial']} of the dataset-mean map's; at the long rung normals "
        f"{1 - LONG_NORMALS_SHARE_OF_PSEUDO:.0%} better than the pseudo-GT that supervised them, and the default "
        "rung's targets too, which the ablation tables' budget check applies at every budget. A layer counts as "
        "learned only where it beats its floor, the dataset-mean map (its error beside it). Test split, mean ± std "
        "over seeds; the floor-and-ceiling section says what the same network reaches on the true layers.\n",
        *head,
        *rows,
        "",
    )
    template_section(rep, groups)
    rep.add(*uv_glance_lines(runs, ladder_runs(runs)))
    rep.add(*without_truth_lines(runs), *albedo_cause_lines(runs), *light_target_lines(runs))
    light_pattern_section(rep, runs)
    if light_rows := light_table(groups):
        rep.add(
            "The light against its floor, the *constant light* (the mean train SH, the same for every face): on the "
            "face (the light's shading through the true normals, si-MSE against the true light's) and in its nine "
            "coefficients (`sh_error`, relative to the true light), split between the SH directions the face's "
            "normals show and those they hide (`disent.eval.metrics.sh_error_shown_hidden`; claim 2 reads it).\n",
            *LIGHT_HEAD,
            *light_rows,
            "",
            *completed_light_lines(runs),
        )
    rep.add(*matte_lines(runs))
    if not any(where == "+experiment=long" for where, _ in groups):
        rep.add(
            "_No run of the long rung is among this build's inputs (`reports/runs.jsonl` has none); the archive page "
            "keeps the rows of runs whose records are gone._\n"
        )


LIGHT_KEYS = (  # (key, label, format): each scored beside its floor, trivial_<key>
    ("light_shading_si_mse", "light on the face", ".4f"),
    ("sh_error", "SH error", ".3f"),
    ("sh_error_shown", "its shown part", ".3f"),
    ("sh_error_hidden", "its hidden part", ".3f"),
)
LIGHT_HEAD = table_head(
    "setting",
    "model",
    *(f"{label}: network / constant light" for _, label, _ in LIGHT_KEYS),
    "beats the constant light",
)


def light_table(groups: dict) -> list[str]:
    """The glance rows of the light (``groups``: ``{(setting, model): runs}``): each of :data:`LIGHT_KEYS` beside the
    constant light's, and where the network's mean beats it; models without a light (or runs scored before the
    split) have none."""
    rows = []
    for (where, model), rs in sorted(groups.items()):
        pairs = [(seed_spread(rs, key), seed_spread(rs, f"trivial_{key}")) for key, _, _ in LIGHT_KEYS]
        if not all(net and floor for net, floor in pairs):
            continue
        cells = [f"{spread_text(net, f)} / {floor['mean']:{f}}" for (_, _, f), (net, floor) in zip(LIGHT_KEYS, pairs)]
        yes, no = (
            [label for (_, label, _), (net, floor) in zip(LIGHT_KEYS, pairs) if (net["mean"] < floor["mean"]) is want]
            for want in (True, False)
        )
        rows.append(
            f"| `{where}` | {model} | {' | '.join(cells)} | "
            f"{'; '.join(filter(None, [', '.join(yes), no and 'not ' + ', '.join(no)]))} |"
        )
    return rows


COMPLETED_HEAD = table_head(
    "setting", "model", "SH error completed", "raw", "L-hat completed / raw", "constant light", "completed beats"
)


def completed_light_lines(runs: list[Run]) -> list[str]:
    """The light completed by the mean light where a face hides it (``sh_error_completed``,
    :func:`disent.eval.scoring.completed_light_metrics`), per setting and model of the runs scored with it, beside
    the raw light, L-hat completed and raw, and the constant light; empty without such runs."""
    groups = by_setting_and_model(
        r for r in runs if r.status == "ok" and r.eval and r.value("sh_error_completed") is not None
    )
    rows = []
    for (where, model), rs in sorted(groups.items()):
        completed, raw = seed_spread(rs, "sh_error_completed"), seed_spread(rs, "sh_error")
        mean = {
            k: (st := seed_spread(rs, k)) and st["mean"]
            for k in ("pseudo_sh_error_completed", "pseudo_sh_error", "trivial_sh_error")
        }
        beats = [
            name
            for name, k in (
                ("the constant light", "trivial_sh_error"),
                ("L-hat completed", "pseudo_sh_error_completed"),
            )
            if mean[k] is not None and completed["mean"] < mean[k]
        ]
        rows.append(
            f"| `{where}` | {model} | {spread_text(completed, '.3f')} | {spread_text(raw, '.3f')} | "
            f"{fmt_value(mean['pseudo_sh_error_completed'], '.3f')} / {fmt_value(mean['pseudo_sh_error'], '.3f')} | "
            f"{fmt_value(mean['trivial_sh_error'], '.3f')} | {', '.join(beats) or 'neither'} |"
        )
    if not rows:
        return []
    return [
        "The light *completed by the mean light*: the estimate along the SH directions its own normals and matte "
        "show, the mean train light (scaled to it there) along those they hide (`disent.eval.metrics.completed_sh`; "
        "L-hat along what the pseudo normals show). No truth enters it, and it models no more of the light than the "
        "face reveals. SH error on all nine coefficients, test split, for the runs scored with it (`python -m "
        "disent.eval.evaluate RUN` scores a finished run again):\n",
        *COMPLETED_HEAD,
        *rows,
        "",
    ]


EDIT_FIGURES = (  # (file pattern of python -m disent.edit measure, caption)
    (
        "fig_*_progression.png",
        "The edits themselves, on the shipped models (`python -m disent.edit measure NAME`): four test faces without "
        "the attribute, their reconstruction, DMT along the paper's manifolds as lambda falls (a smaller lambda moves "
        "further), the barycenter, and the generator's own face with the attribute on.\n",
    ),
    (
        "fig_*_manifolds.png",
        "Each attribute edited on each manifold set of the shipped models, the paper's Fig. 5 for every attribute: "
        "the same faces and strength, one row per set of codes traversed.\n",
    ),
    (
        "fig_relight.png",
        "Relighting on the shipped models, the paper's Fig. 8 on SynthFaces: each face given another face's light by "
        "transfer (detailed albedo, Sec. 5.3), the shading ratio and the network's decode, beside the truth.\n",
    ),
)


def progression_figures(rep: Report, edit_dir: Path) -> None:
    """The figures of :data:`EDIT_FIGURES` that each shipped model's measurement drew, one caption each; nothing
    where none did."""
    shipped = [
        (res.get("model", p.parent.name), p.parent)
        for p in sorted(edit_dir.glob("*/edit.json"))
        if (res := load_json(p)) and res.get("setting") == "shipped" and not res.get("background")
    ]
    for pattern, caption in EDIT_FIGURES:
        shown = [(model, fig) for model, folder in shipped for fig in sorted(folder.glob(pattern))]
        if shown:
            rep.add(caption)
        for model, fig in shown:
            rep.image(fig, f"{model}: {fig.stem[4:].replace('_', ' ')}")


# claim 5's reader-free readings: reading -> (the drawn share whose ceiling, the model's reconstructions of the true
# faces, gates it; the claims' score; their best value), per leakage (the reader's) or per off-target change (none)
CEILINGS = {"drawn share": "drawn_share", "drawn share in the face": "drawn_share_face"}
READER_FREE = {
    f"{name} per {per}": (name, score, DRAWN_READINGS[key][1])
    for name, key in CEILINGS.items()
    for per, score in (("leakage", DRAWN_READINGS[key][0]), ("off-target change", OFF_TARGET_READINGS[key][1]))
}


def manifold_rows(
    model: str, where: str, results: list[dict], score: str, best: str, works, reach=None, keep_gated: str = ""
) -> tuple[list[str], list[tuple], dict]:
    """Claim 5's rows for one model kind and setting: per method and attribute, the paper's manifolds against the best
    other set of the claims' ``score`` (mean ± std over the ``results``' models), read where ``works(attribute, v)``
    holds for ``v`` the best set's mean ``best``. ``reach(attribute, v)`` writes that cell (default ``v`` to two
    places). Gated edits come back as ``(attribute, method, v)``, or as rows with the verdict ``keep_gated``; third, the
    verdict of each ``(method, attribute)``."""
    cells: dict = {}  # (method, attribute) -> manifolds -> [(score, best)] over models
    for res in results:
        for c in res["claims"]:
            if score in c:
                cells.setdefault((c["method"], c["attribute"]), {}).setdefault(c["manifolds"], []).append(
                    (c[score], c[best])
                )
    rows, cannot, verdicts = [], [], {}
    for (method, attribute), sets in cells.items():
        stats = {m: _ablation.mean_std([g for g, _ in v]) for m, v in sets.items()}
        paper = next((m for m in sets if str(m).startswith("paper:")), None)
        if paper is None or stats[paper] is None:
            continue
        others = [m for m in sets if m != paper and stats[m] is not None]
        rival = max(others, key=lambda m: stats[m]["mean"]) if others else None
        reached = max(_ablation.mean_std([b for _, b in v])["mean"] for v in sets.values())
        if not works(attribute, reached):
            verdicts[method, attribute] = keep_gated or "not testable (no set makes the edit)"
            if not keep_gated:
                cannot.append((attribute, method, reached))
                continue
            said = keep_gated
        else:
            said = verdict(stats[paper], stats[rival], "higher") if rival else "– (one code: a reference)"
        verdicts[method, attribute] = said
        rows.append(
            f"| {model} | `{where}` | {method} | {attribute} | {paper[6:]}: {spread_text(stats[paper], '.3g')} | "
            f"{f'{rival}: ' + spread_text(stats[rival], '.3g') if rival else '–'} | "
            f"{reach(attribute, reached) if reach else f'{reached:.2f}'} | {said} |"
        )
    return rows, cannot, verdicts


SOFT_SPLIT = ("psnr_skin_full_scaled", "psnr_skin_soft_scaled")  # the face region under a full / soft model matte


def relight_rows(
    model: str,
    where: str,
    results: list[dict],
    keys: tuple,
    all_methods: bool = False,
    against: tuple = ("input", "ratio"),
    values: tuple = (),
) -> list[str]:
    """One row (a list of at most one) of a relighting table over the edit ``results`` of a setting's models that
    scored each of ``keys`` and ``values`` (:data:`disent.edit.measure.RELIGHT_SCORES`): first transfer's own value of
    each of ``values``, then per key transfer less each method of ``against`` (mean ± std over the models); with
    ``all_methods`` first each method's own score of the one key."""
    scores = [{r["method"]: r for r in res.get("relight") or []} for res in results]
    need = {"transfer", *against}
    scores = [s for s in scores if need <= set(s) and all(k in s["transfer"] for k in (*keys, *values))]
    if not scores:
        return []

    def col(fn, fmt=".2f"):
        return spread_text(_ablation.mean_std([fn(s) for s in scores]), fmt)

    cells = [col(lambda s, k=k: s["transfer"][k], ".0%") for k in values]
    for key in keys:
        if all_methods:
            nan = {key: float("nan")}
            cells += [col(lambda s, m=m: s.get(m, nan)[key]) for m in ("transfer", "ratio", "decode", "input")]
        cells += [col(lambda s, m=m: s["transfer"][key] - s[m][key]) for m in against]
    return [f"| {model} | `{where}` | {' | '.join(cells)} |"]


MATTE_FLOORS = (("pseudo_matte_iou", "M-hat"), ("trivial_matte_iou", "the mean region"))  # (key, name)
MATTE_EDGE_KEYS = ("matte_soft_edge", "matte_soft_inner", "matte_mean_edge", "pseudo_matte_mean_edge")
MATTE_HEAD = table_head(
    "setting",
    "model",
    "matte IoU",
    "M-hat (its supervision)",
    "mean face region",
    "beats",
    "soft: edge band / inside",
    "mean on the edge band: matte / M-hat",
)


def scored_spreads(runs: list[Run], keys: tuple) -> dict:
    """``{(setting, model): {key: mean ± std over seeds}}`` of the finished runs scored with ``keys[0]``, then
    ``("shipped", name)`` for each shipped model whose manifest has it (its metrics, n=1); a key a run lacks is None."""
    from disent.models.shipped import manifest

    groups = by_setting_and_model(r for r in runs if r.status == "ok" and r.eval and r.value(keys[0]) is not None)
    spreads = {group: {k: seed_spread(rs, k) for k in keys} for group, rs in sorted(groups.items())}
    for name, entry in sorted(manifest().items()):
        if keys[0] in entry["metrics"]:
            spreads[("shipped", name)] = {k: _ablation.mean_std([entry["metrics"].get(k)]) for k in keys}
    return spreads


ALBEDO_CAUSES = (  # (key, label): the network's albedo, then the detailed albedo I / S(N, L) with N, L as labelled
    ("albedo_si_mse", "network albedo"),
    ("albedo_detailed_si_mse", "I / S(N, L), the network's N and L"),
    ("albedo_detailed_true_light_si_mse", "its N, the true L"),
    ("albedo_detailed_true_normals_si_mse", "the true N, its L"),
)


def albedo_cause_lines(runs: list[Run]) -> list[str]:
    """What holds the albedo back: the network's albedo and the detailed albedo (Sec. 5.3, the image over the
    shading of Eq. 4) with the network's normals and light, and with one of them made true, each as si-MSE and as a
    share of the mean map's (the albedo target's measure), per setting and model of the runs scored with it and of
    the shipped models; empty where none was."""
    # the newest key first: the runs scored with it
    keys = (ALBEDO_CAUSES[-1][0], *(k for k, _ in ALBEDO_CAUSES[:-1]), "trivial_albedo_si_mse")
    rows = []
    for (where, model), st in scored_spreads(runs, keys).items():
        floor = st["trivial_albedo_si_mse"] and st["trivial_albedo_si_mse"]["mean"]
        cells = [
            f"{spread_text(st[k], '.4f', count=False)} ({st[k]['mean'] / floor:.2f}; n={st[k]['n']})"
            if floor and st[k]
            else spread_text(st[k], ".4f")
            for k, _ in ALBEDO_CAUSES
        ]
        goal = floor and TARGETS["albedo_share_of_trivial"] * floor
        meets = [label for key, label in ALBEDO_CAUSES[2:] if goal and st[key] and st[key]["mean"] <= goal]
        rows.append(
            f"| `{where}` | {model} | {' | '.join(cells)} | {fmt_value(floor, '.4f')} | "
            f"{'; '.join(meets) or ('neither' if goal else '–')} |"
        )
    if not rows:
        return []
    return [
        "What holds the albedo back: the rendered face A (.) S matches the image, so the albedo can only be as right "
        "as the shading S(N, L) (Eq. 4) beside it. The *detailed albedo* I / S (Sec. 5.3) with the network's normals "
        "and light, and with one of the two made true, albedo si-MSE (in brackets: its share of the mean map's, "
        f"the target <= {TARGETS['albedo_share_of_trivial']}), test split (`disent.eval.evaluate`; shipped models: "
        "`python -m disent.models.shipped NAME --add-metrics`). The input whose truth brings the error down most is "
        "the one to supervise better.\n",
        *table_head(
            "setting",
            "model",
            *(label for _, label in ALBEDO_CAUSES),
            "mean map",
            "meets the target with one made true",
        ),
        *rows,
        "",
    ]


def light_target_lines(runs: list[Run]) -> list[str]:
    """What another E_recon-L target buys: each setting trained on one of :data:`LIGHT_TARGETS` against the same
    setting without it (with the paper's L-hat, or the target at its own scale), on the light on the face, its
    contrast and that contrast's pattern and magnitude where both sides were scored with them, the normals and the
    albedo (its share of the mean map's, the albedo target's measure); a paragraph per target, none where no such
    pair was scored."""
    parts = ("light_contrast", "light_pattern_corr", "light_contrast_ratio")
    keys = ("albedo_si_mse", "light_shading_si_mse", "normal_mean", "trivial_albedo_si_mse", *parts)
    spreads = scored_spreads(runs, keys)
    goal, out = TARGETS["albedo_share_of_trivial"], []
    for key, (_, intro) in LIGHT_TARGETS.items():
        lines = []
        for (where, model), st in sorted(spreads.items()):
            picks = setting_picks(where, key)
            base = " ".join(t for t in where.split() if t not in picks) or "(defaults)"
            if not picks or (base, model) not in spreads or not st["trivial_albedo_si_mse"]:
                continue
            ref, floor = spreads[base, model], st["trivial_albedo_si_mse"]["mean"]
            share = [s["albedo_si_mse"]["mean"] / floor for s in (ref, st)]
            light, normals, albedo = (
                f"{spread_text(ref[k], fmt)} -> {spread_text(st[k], fmt)}"
                for k, fmt in (("light_shading_si_mse", ".4f"), ("normal_mean", ".2f"), ("albedo_si_mse", ".4f"))
            )
            for k, words in zip(parts, ("light contrast", "its pattern", "its magnitude")):
                if ref[k] and st[k]:
                    light += f"; {words} {spread_text(ref[k])} -> {spread_text(st[k])}"
            lines.append(
                f"- `{where}` ({model}) against `{base}`: light on the face {light}; normals {normals} deg; albedo "
                f"{albedo}, {share[0]:.2f} -> {share[1]:.2f} of the mean map's: "
                f"{'meets' if share[1] <= goal else 'misses'} the target (<= {goal}).{network_run_words(where, runs)}"
            )
        if lines:
            out += [f"{intro}, test split, mean ± std over seeds:\n", *lines, ""]
    return out


def network_run(where: str, runs: list[Run]) -> Run | None:
    """The run the setting ``where`` names as E_recon-L's network (``loss.recon_L_network=run:ID``, a target drawn
    from a network that was itself trained on a target): that run among ``runs`` (records included), else the
    folder that a run of ``runs`` trained with under that name; None for a shipped model's name."""
    for t in where.split():
        if t.startswith("loss.recon_L_network="):
            ref = run_ref(t.partition("=")[2])
            found = [r for r in runs if r.id == ref]
            if found or ref is None:
                return found[0] if found else None
            for r in runs:  # a run folder names it by its path in its overrides
                for o in map(str, r.overrides):
                    key, _, value = o.lstrip("+").partition("=")
                    folder = Path(value)
                    if key == "loss.recon_L_network" and run_ref(value) == ref and (folder / ".hydra").is_dir():
                        return Run.load(folder)
    return None


def network_run_words(where: str, runs: list[Run]) -> str:
    """What the run folder ``where`` names as E_recon-L's network (:func:`network_run`) was, as a sentence; else
    nothing."""
    run = network_run(where, runs)
    if run is None:
        return ""
    return f" Its network: the {run.model} model trained at `{setting(run, drop_model=True)}`, seed {run.seed}."


LIGHT_TARGET_KEYS = (
    "loss.recon_L_target",
    "loss.recon_L_oracle_mix",
    "loss.recon_L_scale",
    "loss.recon_L_network",
    "loss.recon_L_network_share",
)
RUNGS = ("+experiment=long",)  # a setting's budget override, kept apart from its target


SOURCE_WORDS = {  # target_source's rows, short, for the figure
    "lhat": "L-hat",
    "lhat_eroded": "eroded",
    "texture_model": "texture",
    "texture_model_lhat_scale": "texture at L-hat's scale",
    "true_pixels_normals_albedo": "truth's shape",
    **{f"oracle_mix_{m}": f"dose {m}" for m in ("0.25", "0.5", "0.75")},
    **{f"network_{m}": f"{m}'s light" for m in ("explicit", "implicit")},
    **{f"network_{m}_texture": f"{m}'s light + refit" for m in ("explicit", "implicit")},
}


def only_light_target(where: str) -> bool:
    """Whether the setting ``where`` changes E_recon-L's target alone (:data:`LIGHT_TARGET_KEYS`) and its rung."""
    tokens = [t for t in where.split() if t not in (*RUNGS, "(defaults)")]
    return all("=" in t and t.split("=", 1)[0] in LIGHT_TARGET_KEYS for t in tokens)


def drawn_target_words(where: str, runs: list[Run]) -> str:
    """A short name, for the figure, of a network target the lighting table has no row for: whose light (a shipped
    model's, or a run's: :func:`network_run`), with the refit and its share where they are."""
    picks = dict(t.split("=", 1) for t in where.split() if t.startswith("loss.recon_L_"))
    run = network_run(where, runs)
    whose = f"{run.model} run" if run else picks.get("loss.recon_L_network", "explicit")
    refit = picks.get("loss.recon_L_target") == "sh_network_texture"
    share = f" ({picks['loss.recon_L_network_share']})" if "loss.recon_L_network_share" in picks else ""
    return f"{whose}'s light" + (f" + refit{share}" if refit else "")


def target_source(where: str) -> str | None:
    """The row of the lighting section's ``lhat_sources.json`` that is E_recon-L's target under the setting ``where``
    (L-hat, L-hat eroded, the texture model at its own or L-hat's scale, an oracle dose; the truth's shape for the
    true light or a full dose), or None where the setting changes anything else (a refit at another share too)."""
    from disent.config import ADDED_LATER

    if not only_light_target(where):
        return None
    picks = dict(t.split("=", 1) for t in where.split() if t.startswith("loss."))
    target, scale = picks.get("loss.recon_L_target", "sh_pseudo"), picks.get("loss.recon_L_scale", "target")
    mix = float(picks.get("loss.recon_L_oracle_mix", 0))
    if target == "sh" or mix == 1:
        return "true_pixels_normals_albedo"  # the truth's shape (at L-hat's or the texture model's scale)
    if mix:
        return f"oracle_mix_{picks['loss.recon_L_oracle_mix']}" if target == "sh_pseudo" else None
    texture = "texture_model_lhat_scale" if scale == "sh_pseudo" else "texture_model"
    network = f"network_{picks.get('loss.recon_L_network', 'explicit')}"  # a shipped model's row
    share = ADDED_LATER["loss.recon_L_network_share"]
    if float(picks.get("loss.recon_L_network_share", share)) != share:
        return None  # the table's refit rows are at the default share
    return {
        "sh_pseudo": "lhat",
        "sh_pseudo_eroded": "lhat_eroded",
        "sh_texture": texture,
        "sh_network": network,
        "sh_network_texture": f"{network}_texture",
    }.get(target)


# what the albedo is set against (light_pattern_section): (point key, axis label, lower is better)
ALBEDO_AGAINST = (
    ("target_pattern", "target's pattern (corr. of log shading with the truth)", False),
    ("light_log_error", "network's own light: log error", True),
    ("shading_log_error", "network's own shading (its normals too): log error", True),
)


MODEL_MARKERS = {"explicit": None, "implicit": "none"}  # light_pattern_section's models: filled, hollow markers


def shipped_setting(name: str, full: bool = False) -> str:
    """The setting the shipped weights ``name`` trained at: in :func:`target_source`'s terms (the long rung where
    they ran its steps, E_recon-L's target and oracle dose where not L-hat's; a config older than those options
    trained on L-hat), or with ``full`` every setting that defines a run, as :func:`disent.runs.setting` reads
    a run today."""
    from disent.config import ABSENT, config_changes

    run = shipped_run(name)
    if full:
        return setting(run, drop_model=True)
    changes = config_changes(run.cfg, composed_config(tuple(run.overrides)), LIGHT_TARGET_KEYS)  # absent: ADDED_LATER
    overrides = [f"{k}={typed(old)}" for k, (old, _) in changes.items() if old is not ABSENT]
    return " ".join([*run.overrides, *overrides]) or "(defaults)"


def light_pattern_section(rep: Report, runs: list[Run]) -> None:
    """The albedo against its E_recon-L target's pattern, magnitude and log error (the lighting section's
    ``lhat_sources.json``, else its runs' own ``target_light_*``), the network's own light's
    (``light_pattern_corr``, ``light_contrast_ratio``, ``light_log_error``) and its shading's log error
    (``shading_log_error``), one row per setting that changes the target alone (:func:`target_source`), explicit,
    at each rung; with a figure and the rank correlations (:func:`albedo_rank_reading`). Nothing without that
    file."""
    sources = load_json(rep.out / "lighting" / "lhat_sources.json")
    rows, points, shipped = light_pattern_rows(runs, sources) if sources else ([], [], {})
    if not rows:
        return
    explicit = [p for p in points if p["model"] == "explicit"]  # the readings below: one model's settings
    caps = normals_caps(explicit)
    fig, rect = albedo_against_light_figure(points, caps)
    rep.add(
        "The albedo against its light: each setting above that changes E_recon-L's target alone (explicit, and "
        "the implicit model where it trained on one of them: hollow in the figure), with "
        "the target's pattern, magnitude and log error (the lighting section's table: the correlation of its log "
        "shading with the truth's, the ratio of their spreads, and what both leave wrong; "
        "`disent.eval.metrics.log_shading_agreement`; a target the table has no row for, as its runs scored it on "
        "the same test faces: `target_light_*`), the same for the network's own light through the true normals "
        "(`light_pattern_corr`, `light_contrast_ratio`, `light_log_error`), and the log error of the network's own "
        "shading, its normals and light together, against the true shading (`shading_log_error`), mean ± std over "
        "seeds (– where its runs were scored before them); the albedo as a share of the mean map's. Test split."
        + "".join(
            f" `shipped` ({model}): the shipped {model} weights, one seed of `{at}` as their manifest's config reads "
            f"(`python -m disent.models.shipped {model} --add-metrics`), a row of the table only."
            for model, at in shipped.items()
        )
        + "\n",
        *table_head(
            "setting",
            "model",
            "rung",
            "target: pattern",
            "target: magnitude",
            "target: log error",
            "network's light: pattern",
            "magnitude",
            "log error",
            "network's shading: log error",
            "albedo / mean map's",
        ),
        *sorted(rows, key=lambda r: (r.split(" | ")[2], r.split(" | ")[1], r.split(" | ")[3])),  # rung, model, pattern
        "",
    )
    rep.figure(
        fig, "albedo_vs_light_pattern.png", "the albedo against its target's pattern and its network's errors", rect
    )
    rep.add(albedo_rank_reading(explicit), normals_cap_reading(explicit, caps), "")


def light_pattern_rows(runs: list[Run], sources: dict) -> tuple[list[str], list[dict], dict]:
    """The rows of :func:`light_pattern_section`, the figure's points (one per setting) and the shipped models'
    settings."""
    net_keys = ("light_pattern_corr", "light_contrast_ratio", "light_log_error", "shading_log_error")
    own_keys = {f"target_light_{k}": k for k in ("pattern_corr", "contrast_ratio", "log_error")}
    cap_key = "albedo_detailed_true_light_si_mse"  # I / S(N, L) with its N and the true L: what its normals allow
    rows, points, shipped = [], [], {}
    for (where, model), st in scored_spreads(
        runs, ("albedo_si_mse", "trivial_albedo_si_mse", *net_keys, cap_key, *own_keys)
    ).items():
        # the shipped weights: one seed of their setting (the manifest's config)
        trained_at = shipped_setting(model) if where == "shipped" else where
        source = target_source(trained_at)
        row = sources["rows"].get(source or "")
        if not row and where != "shipped" and all(st[k] for k in own_keys) and only_light_target(where):
            # no row for it (a network of a run folder, another share): its runs scored the target themselves
            row, source = {v: st[k]["mean"] for k, v in own_keys.items()}, drawn_target_words(where, runs)
        if model not in MODEL_MARKERS or not row or "pattern_corr" not in row or not st["trivial_albedo_si_mse"]:
            continue
        floor = st["trivial_albedo_si_mse"]["mean"]
        share = {k: st["albedo_si_mse"][k] / floor for k in ("mean", "std")}
        rung = "long" if "+experiment=long" in trained_at.split() else "default"
        mean = {k: st[k] and st[k]["mean"] for k in net_keys}
        name = SOURCE_WORDS.get(source, source)
        cap = st[cap_key] and st[cap_key]["mean"] / floor
        if where == "shipped":
            shipped[model] = trained_at
        else:  # the figure and the ranks: one point per setting (the shipped seed is one of its runs)
            points.append(
                {
                    "model": model,
                    "rung": rung,
                    "name": name,
                    "share": share,
                    "target_pattern": row["pattern_corr"],
                    "cap": cap,
                    **mean,
                }
            )
        rows.append(
            f"| `{where}` | {model} | {rung} | {row['pattern_corr']:.3f} | {row['contrast_ratio']:.2f} | "
            f"{fmt_value(row.get('log_error'), '.3f')} | "
            + " | ".join(
                spread_text(st[k], f) if st[k] else "–" for k, f in zip(net_keys, (".3f", ".2f", ".3f", ".3f"))
            )
            + f" | {share['mean']:.2f} ± {share['std']:.2f} (n={st['albedo_si_mse']['n']}) |"
        )
    return rows, points, shipped


def albedo_against_light_figure(points: list[dict], caps: dict):
    """The albedo's share of the mean map's against each measure of :data:`ALBEDO_AGAINST`, a point per setting
    and rung, its normals' cap dotted; returns the figure and the rect its legend leaves the panels."""
    plt = pyplot()
    fig, axes = plt.subplots(1, len(ALBEDO_AGAINST), figsize=(15, 4.6), sharey=True)
    rect = (0, 0.1, 1, 1)  # the legend below the panels
    labels_of = []  # each panel's point labels
    for ax, (key, label, lower) in zip(axes, ALBEDO_AGAINST):
        labels = []
        labels_of.append(labels)
        for (rung, marker), colour in zip((("default", "o"), ("long", "s")), ("C0", "C1")):
            if rung in caps:
                ax.axhline(caps[rung], color=colour, lw=0.8, ls=":", label=f"{rung} rung: its normals, the true light")
            for model, fill in MODEL_MARKERS.items():
                here = [p for p in points if (p["rung"], p["model"]) == (rung, model) and p[key] is not None]
                if not here:
                    continue
                x, y, e = (
                    [p[key] for p in here],
                    [p["share"]["mean"] for p in here],
                    [p["share"]["std"] for p in here],
                )
                ax.errorbar(x, y, e, fmt=marker, color=colour, mfc=fill or colour, capsize=3, label=f"{rung}, {model}")
            labels += [
                ax.annotate(
                    p["name"],
                    (p[key], p["share"]["mean"]),
                    textcoords="offset points",
                    xytext=(4, 3),
                    fontsize=7,
                    arrowprops={"arrowstyle": "-", "lw": 0.4, "color": "0.5", "shrinkA": 0, "shrinkB": 2},
                )
                for p in points
                if p["rung"] == rung and p[key] is not None
            ]
        ax.axhline(TARGETS["albedo_share_of_trivial"], color="k", lw=0.8, ls="--", label="albedo target")
        ax.set_xlabel(label)
        ax.grid(alpha=0.3)
        if lower:
            ax.invert_xaxis()  # better to the right on every panel
    axes[0].set_ylabel("albedo si-MSE / mean map's")
    fig.legend(*axes[0].get_legend_handles_labels(), loc="lower center", ncol=4, fontsize=8)
    fig.tight_layout(rect=rect)  # the final layout, before the labels are moved apart in it
    for ax, labels in zip(axes, labels_of):
        unoverlap(ax, labels)
    return fig, rect


def normals_caps(points: list[dict]) -> dict:
    """``{rung: share}``: the mean over a rung's settings of the detailed albedo with the network's normals under the
    true light (``cap``, a share of the mean map's): how far its normals let the albedo go whatever its light."""
    caps = {}
    for rung in ("default", "long"):
        if here := [p["cap"] for p in points if p["rung"] == rung and p.get("cap") is not None]:
            caps[rung] = sum(here) / len(here)
    return caps


def normals_cap_reading(points: list[dict], caps: dict) -> str:
    """One sentence on the ``caps`` (:func:`normals_caps` of ``points``) against the albedo target, beside the albedo
    of the networks trained on the truth's shape (the oracle's points) at the same rung; "" without caps."""
    if not caps:
        return ""
    goal, oracle = TARGETS["albedo_share_of_trivial"], SOURCE_WORDS["true_pixels_normals_albedo"]
    parts = []
    for rung, share in caps.items():
        part = f"{rung} rung {share:.2f} ({'within' if share <= goal else 'short of'} the target"
        if truth := [p["share"]["mean"] for p in points if p["rung"] == rung and p["name"] == oracle]:
            part += f"; trained on the true light's shape the albedo ends at {min(truth):.2f}"
        parts.append(part + ")")
    return (
        "What the networks' normals allow: the detailed albedo I / S(N, L) with each network's own normals under the "
        "true light (`albedo_detailed_true_light_si_mse`, the mean over the rung's explicit settings above, dotted in "
        f"the figure), a share of the mean map's: {'; '.join(parts)}. Where it is short of the target (<= {goal}), a "
        "better light alone is not expected to bring the albedo there at that budget; the normals must improve too.\n"
    )


def albedo_rank_reading(points: list[dict]) -> str:
    """Spearman's rank correlation over settings, per rung, of the albedo share with each of :data:`ALBEDO_AGAINST`
    (``points``: dicts with ``rung``, ``share`` and those keys, None where unscored), where at least 4 settings have
    distinct values; signed so that +1 means the better value always goes with the better albedo."""
    from scipy.stats import spearmanr

    parts = []
    for rung in ("default", "long"):
        for key, label, lower in ALBEDO_AGAINST:
            xy = [(p[key], p["share"]["mean"]) for p in points if p["rung"] == rung and p.get(key) is not None]
            if len(xy) >= 4 and len({x for x, _ in xy}) > 1:
                rho = spearmanr(*zip(*xy)).statistic * (1 if lower else -1)
                parts.append(f"{rung} rung, the {label}: {rho:+.2f} over {len(xy)} settings")
    if not parts:
        return ""
    return (
        "Rank agreement over the explicit settings (Spearman's correlation, +1 where the better value always goes "
        "with the better albedo): " + "; ".join(parts) + ".\n"
    )


def matte_lines(runs: list[Run]) -> list[str]:
    """The matte against the true face region (``matte_iou``, :func:`disent.eval.scoring.metrics_from_outputs`) per
    setting and model of the runs scored with it and of the shipped models (their manifest's metrics), beside M-hat's
    and the mean train face region's; empty where none was scored."""
    spreads = scored_spreads(runs, ("matte_iou", *(k for k, _ in MATTE_FLOORS), *MATTE_EDGE_KEYS))
    rows = []
    for (where, model), st in spreads.items():
        net, floors = st["matte_iou"], [(st[k] and st[k]["mean"], name) for k, name in MATTE_FLOORS]
        beats = [name for floor, name in floors if floor is not None and net["mean"] > floor]
        edge = [fmt_value(st[k] and st[k]["mean"], ".2f") for k in MATTE_EDGE_KEYS]
        rows.append(
            f"| `{where}` | {model} | {spread_text(net, '.3f')} | "
            + " | ".join(fmt_value(floor, ".3f") for floor, _ in floors)
            + f" | {', '.join(beats) or 'neither'} | {edge[0]} / {edge[1]} | {edge[2]} / {edge[3]} |"
        )
    if not rows:
        return []
    return [
        "The matte against the true face region (`mask_face`: the skin a 3DMM covers, not hair, ears or neck; the "
        "region the matte's supervision M-hat estimates, Sec. 3.3), IoU cut at 0.5 (higher is better), beside M-hat's "
        "own and the mean train face region's, test split. *Soft*: the share of the face region's edge band (the "
        f"pixels within {MATTE_EDGE} px of its edge) and of its inside (deeper than {2 * MATTE_EDGE} px) where the "
        f"matte is under {FACE_THRESHOLD:g}; beside it the mean of the matte and of M-hat on the edge band. Where "
        "the two means agree, the soft edge is what the matte's L2 loss toward a binary M-hat asks for: M-hat's "
        "expectation where the image does not say where M-hat's edge falls "
        "(`disent.eval.scoring.matte_edge_metrics`; `loss.matte_p=1`: the release's L1 toward M-hat instead, "
        "whose minimiser is M-hat's median, not its expectation). `shipped`: the shipped weights, scored by "
        "`python -m disent.models.shipped NAME --add-metrics`; runs score it themselves, and "
        "`python -m disent.eval.evaluate RUN` scores a finished run again.\n",
        *MATTE_HEAD,
        *rows,
        "",
    ]


def edit_rates(results: list[dict], attribute: str) -> dict:
    """``{"truth reconstructed": spread, "truth": spread, "drawn share": spread, "drawn share in the face": spread}``
    over the edit results of a setting's models: how often the reader calls ``attribute`` on the model's
    reconstructions of faces that have it, and on those faces, and the share of the generator's change the
    reconstructions draw (:func:`disent.edit.measure.drawn_share`, no reader), over the image and inside the face
    region; a key is missing where no result measured it."""
    rates = {}
    for name, m, key in (
        ("truth reconstructed", "truth reconstructed", "success"),
        ("truth", "truth", "success"),
        *((name, "truth reconstructed", key) for name, key in CEILINGS.items()),
    ):
        found = [
            r[key]
            for res in results
            for r in res.get("traversal") or []
            if r["attribute"] == attribute and r["method"] == m and key in r
        ]
        if found:
            rates[name] = _ablation.mean_std(found)
    return rates


def beyond_the_fit(groups: dict) -> list[str]:
    """Claim 1 pixel by pixel: the network's and the pseudo-GT's normal error where the pseudo-GT errs by each
    range of :data:`disent.eval.scoring.PSEUDO_ERROR_BINS` (``groups``: ``{(setting, model): runs}``; runs
    scored before the bins were kept show none)."""
    from disent.eval.scoring import PSEUDO_ERROR_BINS

    bins = [f"{lo}_{hi}" for lo, hi in zip(PSEUDO_ERROR_BINS, PSEUDO_ERROR_BINS[1:])]
    rows, readings = [], []
    for (where, model), rs in sorted(groups.items()):
        cells, side = [], {"beats": [], "loses to": []}
        for b in bins:
            keys = (f"normal_mean_where_pseudo_{b}", f"pseudo_normal_mean_where_pseudo_{b}", f"share_where_pseudo_{b}")
            net, pseudo, share = (seed_spread(rs, k) for k in keys)
            if model in ("explicit", "implicit") and net and pseudo and share:
                cells.append(f"{spread_text(net)} / {pseudo['mean']:.2f} ({100 * share['mean']:.0f} %)")
                if abs(net["mean"] - pseudo["mean"]) > net["std"]:  # beyond the seed spread
                    side["beats" if net["mean"] < pseudo["mean"] else "loses to"].append(b.replace("_", "-"))
        if len(cells) == len(bins):
            rows.append(f"| `{where}` | {model} | " + " | ".join(cells) + " |")
            found = [f"{how} the pseudo-GT where that errs by {', '.join(bs)} deg" for how, bs in side.items() if bs]
            readings.append(f"- `{where}`: the network {'; it '.join(found) or 'ties the pseudo-GT in every bin'}.")
    if not rows:
        return []
    return [
        "Where it goes beyond: the scored pixels binned by the pseudo-GT's own error against the truth; in each bin "
        "the network's error (mean ± std over seeds) / the pseudo-GT's (deg), and the bin's share of the pixels "
        "(`disent.eval.scoring.PSEUDO_ERROR_BINS`; runs scored before these bins: "
        "`python -m disent.eval.evaluate RUN` rescores them).\n",
        *table_head("setting", "model", *(f"pseudo-GT off by {b.replace('_', '-')} deg" for b in bins)),
        *rows,
        "",
        *readings,
    ]


def tally(verdicts) -> str:
    """Verdicts of several readings of one claim in one cell: each verdict (less its reason) and how many readings
    give it, of all (``**confirmed** 3, not resolved 2 of 5``)."""
    said = [verdict_word(v) for v in verdicts]
    counts = {v: said.count(v) for v in dict.fromkeys(sorted(said))}
    return ", ".join(f"{v} {n}" for v, n in counts.items()) + f" of {len(said)}"


def lower_than_fixed(*pairs: tuple) -> str:
    """One verdict over ``(spread over seeds, a deterministic estimator's value)`` pairs: the network lower on
    each (:func:`verdict`), or ``mixed`` naming the verdicts where they differ."""
    verdicts = {verdict(net, {"mean": fixed, "std": 0.0, "n": net["n"]}, "lower") for net, fixed in pairs}
    return verdicts.pop() if len(verdicts) == 1 else "mixed: " + " / ".join(sorted(verdicts))


def shown_variance_table(rep: Report, groups: dict, est: dict, glance: Glance) -> list[str]:
    """Claim 2 on the light the faces show: per ``(model, setting)`` group of the SH-variance protocol's rows, the
    within-condition variance and the error in the SH directions a face shows
    (:func:`disent.eval.protocols.sh_variance_shown_hidden`), against L-hat's and the mean light's."""
    ls, mean_light = est.get("ls_pseudo") or {}, est.get("mean_light") or {}
    if "variance_shown" not in ls:
        return []
    head = table_head(
        "model", "setting", "shown variance", "L-hat", "mean light", "shown SH error", "L-hat", "mean light", "verdict"
    )
    rows = []
    for (model, where), measured in sorted(groups.items()):
        measured = [r for r in measured if "variance_shown" in r]
        if not measured:
            continue
        var, err = (_ablation.mean_std([r[k] for r in measured]) for k in ("variance_shown", "sh_error_shown"))
        said = lower_than_fixed((var, ls["variance_shown"]), (err, ls["sh_error_shown"]))
        glance.put("2", "shown directions: variance and SH error below L-hat's", where, model, said)
        rows.append(
            f"| {model} | `{where}` | {spread_text(var, '.3f')} | {ls['variance_shown']:.3f} | "
            f"{mean_light.get('variance_shown', float('nan')):.3f} | {spread_text(err, '.3f')} | "
            f"{ls['sh_error_shown']:.3f} | "
            f"{mean_light.get('sh_error_shown', float('nan')):.3f} | "
            f"{said} |"
        )
    if not rows:
        return []
    return [
        "The same protocol on the light the faces show: a face's normals cover part of the sphere, so L-hat's "
        "least squares spreads freely along the SH directions its shading hides, and a lower variance there says "
        "nothing about the light. Within-condition variance and SH error in the shown directions "
        "(`variance_shown`, `sh_error_shown`; each estimate scaled to the truth in shading, a share of the true "
        "light's squared norm), against L-hat's and the constant mean light's (whose only spread is its scale). "
        "Confirmed where the network is lower than L-hat on both beyond its seed spread.\n",
        *head,
        *rows,
        "",
    ]


def shown_hidden_lines(runs: list[Run], glance: Glance) -> list[str]:
    """Claim 2's reading of the SH error split by what a face shows (``sh_error_shown`` / ``sh_error_hidden``),
    per setting and model over the runs scored with it, beside the mean light and L-hat on the same images; the
    verdict (shown error below the mean light's) also put in ``glance``."""
    scored = [r for r in runs if r.value("sh_error_shown") is not None]
    if not scored:
        return []
    head = table_head(
        "setting",
        "model",
        "shown SH error",
        "hidden SH error",
        "filled from the mean light",
        "all 9 coefficients",
        "learned: shown below the mean light's",
        "all 9 below the mean light's",
    )
    rows = []
    for (where, model), rs in sorted(by_setting_and_model(scored).items()):
        if model not in ("explicit", "implicit"):
            continue
        shown, hidden, filled = (seed_spread(rs, f"sh_error_{k}") for k in ("shown", "hidden", "completed"))
        said = verdict(shown, seed_spread(rs, "trivial_sh_error_shown"), "lower")
        whole = verdict(seed_spread(rs, "sh_error"), seed_spread(rs, "trivial_sh_error"), "lower")
        glance.put("2", "light learned: shown SH error below the mean light's", where, model, said)
        glance.put("2", "light learned: SH error, all 9 coefficients, below the mean light's", where, model, whole)
        cells = (spread_text(v, ".3f") for v in (shown, hidden, filled, seed_spread(rs, "sh_error")))
        rows.append(f"| `{where}` | {model} | " + " | ".join(cells) + f" | {said} | {whole} |")

    def mean(key):  # of a light that is the same for every run: the mean light's, L-hat's
        return fmt_value((seed_spread(scored, key) or {}).get("mean"), ".3f")

    fixed = (
        f"the mean light {mean('trivial_sh_error_shown')} shown / {mean('trivial_sh_error_hidden')} hidden / "
        f"{mean('trivial_sh_error')} filled and all 9 (itself); L-hat {mean('pseudo_sh_error_shown')} shown / "
        f"{mean('pseudo_sh_error_hidden')} hidden / {mean('pseudo_sh_error_completed')} filled"
    )
    return [
        "The SH error split by what the face shows (`sh_error_shown` / `sh_error_hidden`, test split, relative to "
        "the true light; `disent.eval.metrics.sh_error_shown_hidden`): a face's normals cover part of the sphere, "
        "so the SH directions whose shading over the face carries under 1 % of the largest direction's energy (on "
        "frontal normals ambient, n_z and 3 n_z^2 - 1 are nearly collinear, as are n_y and n_y n_z) are hidden from "
        "any image of it; the scale is read from the shading. A light counts as learned where its shown error beats "
        "the mean light's (over the seeds, beyond their spread); the hidden part is a guess that only a prior (the "
        "mean light's) can make well, so *filled* scores each light with its hidden part taken from the mean light "
        f"(`sh_error_completed`; section *At a glance*). On the same images: {fixed}.\n",
        *head,
        *rows,
        "",
    ]


def background_lines(measured: list[tuple]) -> list[str]:
    """The edits made through the background code (``python -m disent.edit measure RUN --background``): per model,
    attribute and method, the best success of the manifold sets with the background code against those without."""
    lines = []
    for model, where, res in measured:
        best: dict = {}  # (attribute, method) -> {with background: best success}
        for c in res["claims"]:
            cell, with_bg = best.setdefault((c["attribute"], c["method"]), {}), "bg" in c["manifolds"].split("+")
            cell[with_bg] = max(cell.get(with_bg, 0.0), c["best_success"])
        cells = [
            f"{attribute} by {method}: {v[True]:.2f} with it, {v[False]:.2f} with the face codes alone"
            for (attribute, method), v in best.items()
            if {True, False} <= set(v)
        ]
        if cells:
            lines.append(f"- {model} (`{where}`): " + "; ".join(cells) + ".")
    if not lines:
        return []
    return [
        "Outside the face: the same measurement with the background code among the manifold sets "
        "(`python -m disent.edit measure RUN --background`; best success). An edit the face codes cannot make but "
        "the background code can is one the reader sees outside the face, in what the model draws as background "
        "(SynthFaces greys a senior face's hair).\n",
        *lines,
        "",
    ]


def sec_claims(rep: Report, runs: list[Run], eval_dir: Path, glance: Glance | None = None) -> None:
    """The paper's claims, each with its numbers (mean ± std over seeds, grouped by setting) and a verdict; the
    verdicts at the ladder's rungs also go into ``glance`` (the front page's claims table reads them)."""
    done = ladder_runs(runs)
    if not done:
        rep.note(
            "no finished runs of the plain models; train them (`python -m disent -m model=baseline,explicit,"
            "implicit seed=0,1,2`) and run the report again."
        )
        return
    rep.add(
        f"Each verdict needs {MIN_SEEDS} seeds per arm and a difference larger than the arms' seed spread "
        "(std). Runs of the budget ladder only (the defaults, `+experiment=long`; no other override), grouped by "
        "their *setting*: what one types today to train them again, apart from the seed and the time guard (the "
        "config groups, and each run-defining value that differs from today's `conf/`, so runs trained before a "
        "default changed show the old value). The machines that trained them: the runs page.\n"
    )
    glance, at = glance if glance is not None else Glance(), len(rep.lines)
    try:
        measured_claims(rep, runs, eval_dir, glance)
    finally:  # the verdicts at a glance, above the tables they come from
        if table := glance.lines():
            rep.lines[at:at] = [
                "At a glance: each claim's verdicts at the budget ladder's two rungs (the tables below give the "
                "numbers, the settings off the ladder and why a cell is not testable; –: not measured there). "
                "Claim 5's cells count its readings (the reader's and the reader-free ones of its own table at a "
                "glance) by verdict.\n",
                *table,
            ]


def edit_groups(edit_dir: Path, loaded: dict) -> tuple[dict, list]:
    """The published edit results (``edit/*/edit.json``) by ``(model, setting)`` (its trained models, seeds), and
    the ``--background`` diagnostics as ``(model, setting, result)``; ``loaded``: the runs by id, which name each
    result's setting (:func:`disent.runs.measured_setting`)."""
    groups: dict = {}
    outside = []
    for p in sorted(edit_dir.glob("*/edit.json")):
        res = load_json(p)
        where = measured_setting(res, loaded) if res and res.get("claims") else None
        if where is not None and res.get("background"):
            outside.append((res.get("model", p.parent.name), where, res))
        elif where is not None:
            groups.setdefault((res.get("model", p.parent.name), where), []).append(res)
    return groups, outside


def drawn_rates(results: list[dict]) -> dict:
    """``{attribute: edit_rates}`` of one setting's edit results."""
    return {a: edit_rates(results, a) for a in {c["attribute"] for res in results for c in res["claims"]}}


def reader_rows(model: str, where: str, results: list[dict], drawn: dict) -> tuple[list[str], list[tuple], dict]:
    """Claim 5 read by the attribute classifier (gain per leakage, :func:`manifold_rows`), where some manifold set
    makes the edit and the model can draw the attribute at all (``drawn``: :func:`drawn_rates`)."""

    def reader_works(attribute, success):
        drawable = drawn[attribute].get("truth reconstructed")
        return success >= EDIT_WORKS and not (drawable and drawable["mean"] < EDIT_WORKS)

    return manifold_rows(model, where, results, "gain_per_leak", "best_success", reader_works)


def measured_claims(rep: Report, runs: list[Run], eval_dir: Path, glance: Glance) -> None:
    """The claims' sections, each table's verdicts at the ladder's rungs also put in ``glance``."""
    done, loaded = ladder_runs(runs), {r.id: r for r in runs}  # the runs by id: for the tools' records of them
    rep.add("### 1. The network's normals go beyond the morphable-model fit that supervised them\n")
    claim_normals(rep, done, glance)
    rep.add("", "### 2. The network's light varies less across identities under one light than L-hat\n")
    claim_light(rep, done, eval_dir, loaded, glance)
    rep.add("### 3. The rendering models reconstruct better than the 265-d baseline; the implicit one more sharply\n")
    claim_reconstruction(rep, done, glance)
    rep.add("", "### 4. BWS prevents degenerate shading; each prior does what the paper says\n")
    claim_ablations(rep, runs, glance)
    claim_skin(rep, runs)
    rep.add("### 5. Edits on the paper's manifolds change the attribute with less leakage than other manifolds\n")
    groups, outside = edit_groups(eval_dir.parent / "edit", loaded)
    if claim_edits(rep, groups, glance):
        rep.add(*background_lines(outside))
        progression_figures(rep, eval_dir.parent / "edit")
        relighting(rep, groups)


def claim_normals(rep: Report, done: list[Run], glance: Glance) -> None:
    """Claim 1: the network's normals against the pseudo-GT that supervised them, per setting and model."""
    head = table_head("setting", "model", "network normals (deg)", "pseudo-GT (deg)", "mean map (deg)", "verdict")
    groups: dict = {}
    for r in done:
        groups.setdefault((setting(r), r.model), []).append(r)
    rows = []
    for (where, model), rs in sorted(groups.items()):
        if model not in ("explicit", "implicit"):
            continue
        net, pseudo, mean = (seed_spread(rs, k) for k in ("normal_mean", "pseudo_normal_mean", "trivial_normal_mean"))
        said = verdict(net, pseudo, "lower")
        glance.put("1", "normals closer to the truth than the pseudo-GT's", where, model, said)
        rows.append(
            f"| `{where}` | {model} | {spread_text(net)} | {spread_text(pseudo)} | {spread_text(mean)} | {said} |"
        )
    rep.add(*head, *rows)
    rep.add("", *beyond_the_fit(groups))


def claim_light(rep: Report, done: list[Run], eval_dir: Path, loaded: dict, glance: Glance) -> None:
    """Claim 2: the supplement's protocol on the light bank (``eval/sh_variance.json``) against L-hat, in the shown
    directions too, and the test split's light against the constant mean light."""
    shv = load_json(eval_dir / "sh_variance.json")
    if shv:
        est = shv["estimators"]
        trivial = seed_spread(done, "trivial_sh_error")
        runs_of = shv.get("runs") or {m: {"model": m, "setting": "one run a model"} for m in ("explicit", "implicit")}
        groups: dict = {}  # (model, setting) -> the protocol's rows of its trained models (seeds)
        for name, info in runs_of.items():
            where = measured_setting(info, loaded)
            if name in est and where is not None:
                groups.setdefault((info["model"], where), []).append(est[name])
        ls = est.get("ls_pseudo")
        head = table_head("model", "setting", "relative variance", "L-hat", "SH error", "L-hat", "verdict")
        rows = []
        for (model, where), measured in sorted(groups.items()) if ls else ():
            rel, err = (_ablation.mean_std([r[k] for r in measured]) for k in ("relative", "sh_error"))
            said = lower_than_fixed((rel, ls["relative"]), (err, ls["sh_error"]))
            glance.put("2", "light bank: variance and SH error below L-hat's", where, model, said)
            rows.append(
                f"| {model} | `{where}` | {spread_text(rel, '.3f')} | {ls['relative']:.3f} | "
                f"{spread_text(err, '.3f')} | "
                f"{ls['sh_error']:.3f} | {said} |"
            )
        if rows:
            rep.add(
                "Relative variance and SH error on the light bank (`python -m disent.eval.protocols --every-run`), "
                "mean ± std over the trained models of a setting, against L-hat's (a deterministic fit: no "
                "spread). Confirmed where the network is lower on both beyond its seed spread.\n",
                *head,
                *rows,
            )
        rep.add("", *shown_variance_table(rep, groups, est, glance))
        if trivial:
            rep.add(
                f"- The constant mean light scores SH error {trivial['mean']:.3f} on the test split: lower variance "
                "than L-hat is not by itself evidence of a learned light (section *Lighting stability*)."
            )
    else:
        rep.note("`reports/eval/sh_variance.json`; run `python -m disent.eval.protocols` and publish it.")
    rep.add("", *shown_hidden_lines(done, glance), "")  # the test split's light, with or without the light bank


def claim_reconstruction(rep: Report, done: list[Run], glance: Glance) -> None:
    """Claim 3: face PSNR against the 265-d baseline; the implicit model's face SSIM and albedo details against the
    explicit model's."""
    head = table_head(
        "setting",
        "baseline face PSNR",
        "explicit",
        "implicit",
        "explicit > baseline",
        "implicit > baseline",
        "implicit > explicit (face SSIM: baseline / explicit / implicit)",
        "implicit's albedo details > explicit's (detail error: explicit / implicit)",
    )
    rows = []
    across: dict = {}
    for where, rs in group_by_setting(done).items():
        for r in rs:
            across.setdefault(where, {}).setdefault(r.model, []).append(r)
    for where, by_model in sorted(across.items()):
        if "baseline" not in by_model or not ({"explicit", "implicit"} & set(by_model)):
            continue
        psnr = {m: seed_spread(by_model.get(m, []), "recon_face_psnr") for m in ("baseline", "explicit", "implicit")}
        ssim = {m: seed_spread(by_model.get(m, []), "recon_face_ssim") for m in ("baseline", "explicit", "implicit")}
        fine = {m: seed_spread(by_model.get(m, []), "albedo_fine_si_mse") for m in ("explicit", "implicit")}
        above_baseline = {m: verdict(psnr[m], psnr["baseline"], "higher") for m in ("explicit", "implicit")}
        sharper = verdict(ssim["implicit"], ssim["explicit"], "higher")
        finer = verdict(fine["implicit"], fine["explicit"], "lower")
        for m in ("explicit", "implicit"):
            if m in by_model:
                glance.put("3", "face PSNR above the 265-d baseline's", where, m, above_baseline[m])
        if "implicit" in by_model:
            glance.put("3", "face SSIM above the explicit model's", where, "implicit", sharper)
            glance.put("3", "albedo details closer than the explicit model's", where, "implicit", finer)
        rows.append(
            f"| `{where}` | {spread_text(psnr['baseline'])} | {spread_text(psnr['explicit'])} | "
            f"{spread_text(psnr['implicit'])} | {above_baseline['explicit']} | {above_baseline['implicit']} | "
            f"{sharper} ({' / '.join(spread_text(ssim[m], '.3f') for m in ('baseline', 'explicit', 'implicit'))}) | "
            f"{finer} ({' / '.join(spread_text(fine[m], '.5f') for m in ('explicit', 'implicit'))}) |"
        )
    rep.add(
        'Sec. 3.2: in the implicit model\'s UV space "facial features are aligned", so "the network has to learn a '
        'smaller space of variation, leading to sharper, more accurate reconstructions". Two readings of *sharper*: '
        "the face's SSIM (structure), and the error of the albedo's details (`albedo_fine_si_mse`: the albedo's "
        "scale-invariant error below a 2-px blur, eyes, brows, lips; the floor-and-ceiling section's *detail*), the "
        "layer the implicit model draws in UV space. Test split, mean ± std over seeds.\n",
        *head,
        *rows,
    )


def edit_readings(groups: dict) -> tuple[list[str], list[str], dict, dict]:
    """Claim 5's readings of each setting's edit results (``groups``: :func:`edit_groups`): the reader's rows
    (:func:`reader_rows`), the rows of edits no manifold set makes, the reader-free rows by reading
    (:data:`READER_FREE`), and each edit's verdict by reading, ``{(model, setting, method, attribute): {reading:
    verdict}}``."""
    rows, idle, free, edits = [], [], {reading: [] for reading in READER_FREE}, {}
    for (model, where), results in sorted(groups.items()):
        drawn = drawn_rates(results)
        found, cannot, said = reader_rows(model, where, results, drawn)
        rows += found
        for cell, text in said.items():
            edits.setdefault((model, where, *cell), {})["gain per leakage (reader)"] = text
        for reading, (ceiling, score, best) in READER_FREE.items():

            def drawn_ceiling(attribute):  # the share of the true change the model's reconstructions draw
                return (drawn[attribute].get(ceiling) or {}).get("mean")

            def draws_enough(attribute, share):
                return drawn_ceiling(attribute) is not None and share >= EDIT_WORKS * drawn_ceiling(attribute)

            found, _, said = manifold_rows(
                model,
                where,
                results,
                score,
                best,
                draws_enough,
                reach=lambda a, v: f"{v:.0%} of {drawn_ceiling(a):.0%}" if drawn_ceiling(a) is not None else f"{v:.0%}",
                keep_gated=f"not testable (draws under {EDIT_WORKS:.0%} of what the model draws)",
            )
            free[reading] += found
            for cell, text in said.items():
                edits.setdefault((model, where, *cell), {})[reading] = text
        if cannot:
            ceiling = [
                f"{a} {rates['truth reconstructed']['mean']:.2f} (truth {rates['truth']['mean']:.2f}"
                + (f"; {rates['drawn share']['mean']:.0%} of the change drawn)" if "drawn share" in rates else ")")
                for a in dict.fromkeys(a for a, _, _ in cannot)
                if all((rates := drawn[a]).get(m) for m in ("truth reconstructed", "truth"))
            ]
            idle.append(
                f"| {model} | `{where}` | {', '.join(f'{a} by {m} {v:.2f}' for a, m, v in cannot)} | "
                f"{', '.join(ceiling) or '–'} |"
            )
    return rows, idle, free, edits


def claim_edits(rep: Report, groups: dict, glance: Glance) -> bool:
    """Claim 5's tables: the verdicts at a glance, the reader's table, the edits no set makes and each reader-free
    reading (:func:`edit_readings`); False (a note) where no edit result is published."""
    rows, idle, free, edits = edit_readings(groups)
    if not (rows or idle):
        rep.note(
            "`reports/edit/*/edit.json`; run `python -m disent.edit measure explicit` (and `implicit`, or run "
            "folders), then publish its folder."
        )
        return False
    readings = ("gain per leakage (reader)", *READER_FREE)
    glance_rows = [  # the verdicts alone, where some reading has the seeds to give one
        f"| {model} | `{where}` | {method} | {attribute} | "
        + " | ".join(verdict_word(cells.get(r, "–")) for r in readings)
        + " |"
        for (model, where, method, attribute), cells in sorted(edits.items())
        if any(not v.startswith(("not testable", "–")) for v in cells.values())
    ]
    for (model, where, method, attribute), cells in sorted(edits.items()):
        glance.put(
            "5", f"{attribute} by {method}: the paper's manifolds leak less", where, model, tally(cells.values())
        )
    if glance_rows:
        rep.add(
            "At a glance: the verdict of each reading of the claim (the tables below give the numbers, and why a "
            "cell is not testable), for the edits where some reading has the seeds and the edit to give one.\n",
            *table_head("model", "setting", "method", "attribute", *readings),
            *glance_rows,
            "",
        )
    columns = ("model", "setting", "method", "attribute")
    rep.add(
        "Attribute gain per unit leakage over the strengths of each method (`python -m disent.edit measure RUN`, "
        "16 source faces per attribute), mean ± std over the trained models (seeds) of a setting; the paper's "
        "manifolds against the best other manifold set of the same model kind and method. A verdict needs "
        f"{MIN_SEEDS} models and a difference beyond the spread, and is read only where some manifold set makes the "
        f"edit (best success, the share of edited faces read as having the attribute, >= {EDIT_WORKS} on average). "
        "`shipped`: the shipped long-budget weights.\n",
        *table_head(*columns, "paper's manifolds: gain per leakage", "best other", "best success", "verdict"),
        *rows,
        "",
    )
    if idle:
        rep.add(
            IDLE_EDITS,
            *table_head(
                "model",
                "setting",
                "edits no manifold set makes (attribute by method: best success)",
                "faces that have it, reconstructed, read as it",
            ),
            *idle,
            "",
        )
    for reading, text in reader_free_text(groups).items():
        best = f"best {READER_FREE[reading][0].replace('drawn share', 'drawn')}, of what the model draws"
        if free[reading]:
            head = table_head(*columns, f"paper's manifolds: {reading}", "best other", best, "verdict")
            rep.add(text, *head, *free[reading], "")
    return True


IDLE_EDITS = (
    f"Not testable: no manifold set makes the edit (best success < {EDIT_WORKS}), or the model cannot draw "
    f"the attribute (last column < {EDIT_WORKS}). Last column: the share of the model's reconstructions of "
    "the same faces with the attribute truly on that the reader calls positive (beside the true images' "
    "share, the reader's recall). A model draws an edit no more often than it draws the faces that have "
    "the attribute, so a low share says the decoder cannot draw it, and an edit that reads as it anyway "
    "(a best success above the last column) fools the reader rather than drawing the attribute; a high "
    "share says the traversal, not the decoder, fails. Where measured, the share of the generator's change "
    "(the same faces with the attribute on, less off) that the model's reconstructions reproduce "
    "(`disent.edit.measure.drawn_share`, no reader: 100% draws all of it) says how much of it the decoder "
    "draws, however faint for the reader.\n"
)


def reader_free_text(groups: dict) -> dict:
    """What each reader-free reading of claim 5 measures (:data:`READER_FREE`), by reading; the face region's share
    of the generator's change, from the source faces of ``groups``' results."""
    inside: dict = {}  # attribute -> the share of the generator's change in the face region, per result
    for res in (res for results in groups.values() for res in results):
        for r in res.get("traversal") or []:
            if r["method"] == "truth" and "change_in_face" in r:
                inside.setdefault(r["attribute"], []).append(r["change_in_face"])
    in_face = ", ".join(f"{a} {sum(v) / len(v):.0%}" for a, v in inside.items())
    return {
        "drawn share per leakage": "The same claim without the reader: how much of the generator's own change (the "
        "same faces with the attribute on, less off) each edit draws (`disent.edit.measure.drawn_share`: 100% draws "
        "all of it, however faint), summed over the strengths and divided by the summed leakage. The reader, trained "
        "on the generator's sharp renders, misses the faint glasses and smiles a decoder draws; this reading does "
        f"not. Read where some manifold set draws at least {EDIT_WORKS:.0%} of what the model's reconstructions of the "
        "faces that truly have the attribute draw (the ceiling after *of*); the same seeds-and-spread rule.\n",
        "drawn share per off-target change": "And with no reader at all: the leakage too is read off the generator's "
        "change. An edit's *off-target change* is the energy of the part of its change that is not along the "
        "generator's change, over that change's energy (`disent.edit.measure.off_target_share`: 0 for an edit that "
        "changes only what the attribute changes, however strongly); light, pose, identity and background changes "
        "count, and so does an attribute drawn in another place or shape. The drawn shares summed over the strengths, "
        "over the summed off-target changes; ceiling and rule as above.\n",
        "drawn share in the face per leakage": "The same inside the face region only (`mask_face` of the faces with "
        "and without the attribute, the skin a 3DMM covers): the change the face codes are meant to draw. The "
        'paper\'s face masks "do not include hair. This results in less control over some edits, e.g. aging" '
        "(Sec. 5.2, Limitations), and SynthFaces greys a senior face's hair, which no face code reaches: over the "
        "whole image the senior change is mostly hair. Leakage, ceiling and rule as above."
        + (
            " The share of the generator's change inside the face region (`change_in_face`, the source faces): "
            f"{in_face}."
            if in_face
            else ""
        )
        + "\n",
        "drawn share in the face per off-target change": "The same with no reader, inside the face region: both the "
        "drawn share and the off-target change counted there alone.\n",
    }


RELIGHT_TABLES = (  # (key, scores, method differences, values, the table's columns after model and setting)
    (
        "face",
        ("psnr_face",),
        ("input", "ratio"),
        (),
        ("transfer", "ratio", "decode", "input", "transfer - input", "transfer - ratio"),
    ),
    (
        "regions",
        ("psnr_skin", "psnr_skin_scaled", "psnr"),
        ("input", "ratio"),
        (),
        tuple(
            f"transfer - {d}, {w}"
            for w in ("face region", "face region, one scale per image", "whole image")
            for d in ("input", "ratio")
        ),
    ),
    (
        "matte",
        SOFT_SPLIT,
        ("ratio",),
        ("matte_full_share",),
        (
            f"face region under a full matte (> {FACE_THRESHOLD:g})",
            "transfer - ratio there, one scale per image",
            "transfer - ratio under the soft rest, one scale per image",
        ),
    ),
)


def relighting(rep: Report, groups: dict) -> None:
    """Relighting with the detailed albedo (Sec. 5.3) over each setting's edit results: the face's PSNR per method,
    then where the difference lies (:data:`RELIGHT_TABLES`, :func:`relight_rows`)."""
    rows = {key: [] for key, *_ in RELIGHT_TABLES}
    heads = {key: table_head("model", "setting", *columns) for key, *_, columns in RELIGHT_TABLES}
    for (model, where), results in sorted(groups.items()):
        for key, scores, against, values, _ in RELIGHT_TABLES:
            rows[key] += relight_rows(
                model, where, results, scores, all_methods=key == "face", against=against, values=values
            )
    relit, relit_regions, relit_matte = rows["face"], rows["regions"], rows["matte"]
    relit_head, regions_head, matte_head = heads["face"], heads["regions"], heads["matte"]
    rep.add(
        "### Relighting with detailed albedo (Sec. 5.3)\n",
        "PSNR (dB) on the face against the generator's own render of the face under the source light, "
        "8 faces x 6 lights per model, mean ± std over the models of a setting: *transfer* (detailed albedo), the "
        "naive *ratio* image, *decode* (the network re-rendered with the new light), and the unrelit *input* as "
        "the floor.\n",
        *relit_head,
        *relit,
        "",
    )
    if relit_regions:
        rep.add(
            "Where the difference lies: *the face* above is the true matte, the whole head, and transfer relights "
            "only what the model's matte covers, the face region its supervision M-hat marks (Sec. 3.3), leaving "
            "hair, ears and neck as they were. The same relit images scored inside the true face region "
            "(`mask_face`, the skin a 3DMM covers), there after one brightness scale per image (the light's "
            "intensity, read from another face, is confounded with that face's albedo: what is left is the light's "
            "direction and colour), and over the whole image (where the ratio image relights the background too), "
            "PSNR differences in dB:\n",
            *regions_head,
            *relit_regions,
            "",
        )
    if relit_matte:
        rep.add(
            "Why the ratio image leads once the brightness is scaled out: where the model's matte is full, transfer "
            "*is* the ratio image, since its detailed albedo A = I / S shaded anew gives I S' / S (Eqs. 2 and 4); "
            "Eq. 6 then blends the unrelit input in by 1 - M wherever the matte is under 1. The face region split "
            f"by the model's matte (`disent.regions.FACE_THRESHOLD`, {FACE_THRESHOLD:g}), each part with its own "
            "brightness scale per image, PSNR differences in dB:\n",
            *matte_head,
            *relit_matte,
            "",
        )
