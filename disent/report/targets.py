"""At a glance: the budget ladder's runs against the targets of a trainable recipe and their floors, the light's
targets and patterns, the matte (the targets page)."""

from __future__ import annotations

from pathlib import Path

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
    setting_picks,
)
from disent.report.document import Report, unoverlap
from disent.report.tables import (
    by_setting_and_model,
    fmt_value,
    ladder_runs,
    on_the_ladder,
    seed_spread,
    seeds_cell,
    shipped_run,
    spread_text,
    table_head,
)
from disent.report.training import uv_glance_lines
from disent.runs import Run, composed_config, run_ref, setting, typed
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
