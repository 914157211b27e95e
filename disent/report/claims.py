"""The paper's claims, measured (claims 1, 2, 3 and 5; claim 4 is :mod:`disent.report.ablations`; the targets page is
:mod:`disent.report.targets`)."""

from __future__ import annotations

from pathlib import Path

from disent.edit.measure import DRAWN_READINGS, OFF_TARGET_READINGS
from disent.eval import ablation as _ablation
from disent.regions import FACE_THRESHOLD
from disent.report.ablations import (
    claim_ablations,
    claim_skin,
)
from disent.report.document import Report
from disent.report.tables import (
    EDIT_WORKS,
    MIN_SEEDS,
    Glance,
    by_setting_and_model,
    fmt_value,
    ladder_runs,
    seed_spread,
    spread_text,
    table_head,
    verdict,
    verdict_word,
)
from disent.runs import Run, group_by_setting, measured_setting, setting
from disent.storage import load_json

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
