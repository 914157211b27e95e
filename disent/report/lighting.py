"""L-hat uncertainty and lighting model order (``reports/lighting/``, :mod:`disent.lighting`)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from disent.lighting import order_study
from disent.lighting.order_study import ORDER_TARGET, wilson_interval
from disent.report.document import Report
from disent.report.tables import fmt_value, table_head
from disent.storage import load_json


def _pct(x) -> str:
    return "–" if x is None else f"{x:.2f}"


def scenes(entry: dict) -> int:
    """The number of scenes an order-study row was read on (its evidence confusion matrix's total)."""
    return int(np.sum(entry["evidence"]["confusion"]))


def difference_spread(*rows: tuple[float, int], z: float = 1.96) -> float:
    """The 95 % half-width (at ``z = 1.96``) of the difference between accuracies ``(share, n)`` measured on
    independent scenes: two rows closer than this are within each other's sampling spread."""
    return z * math.sqrt(sum(share * (1 - share) / n for share, n in rows))


def residual_text(d: Path) -> str:
    """The residual process's fitted constants, one fit per geometry, from ``residual_process.json`` of the
    lighting folder ``d``."""
    from disent.lighting.geometry import GEOMETRY

    fits = load_json(d / "residual_process.json")
    if not fits:
        return "not fitted in this report's inputs"
    if "rho" in fits:  # one fit, on the pseudo geometry, as studies before the per-geometry fits wrote it
        fits = {"normal_pseudo": fits}
    return "; ".join(
        f"rho {fit['rho']:g}, ell {fit['ell']:g} px from {fit['n_scenes']} {fit['split']} scenes on "
        f"{GEOMETRY[key.partition('+')[0]].label}" + (" beside the geometry noise" if "+" in key else "")
        for key, fit in fits.items()
    )


def band2_reading(order: dict, chosen: str) -> str:
    """One sentence on the order study's band-2 diagnostic: on test, how much band 2 the largest candidate fits for
    a true order-1 scene, on true normals, on pseudo normals with the known albedo, and on the ``chosen`` row, against
    the true order-2 lights' ("" where the study predates it)."""
    rows = {
        "true normals (texture model)": "test/texture/normal",
        "pseudo normals with the known albedo": "test/known/normal_pseudo",
        "the chosen row": f"test/{chosen}",
    }
    band2 = {label: order.get(key, {}).get("band2_share") for label, key in rows.items()}
    if not all(band2.values()):
        return ""
    truth = band2["the chosen row"]["true_order2"]
    return (
        " What separates order 1 from order 2 is the light's band 2. On test, the order-2 fit of a true order-1 scene "
        "holds in band 2, as a share of bands 0 and 1: "
        + ", ".join(f"{b['fitted_by_true_order'][1]:.2f} on {label}" for label, b in band2.items())
        + f"; a true order-2 light holds {truth:.2f}. Where the pseudo geometry's error alone puts as much in band 2 "
        "as a true order-2 light has, the scene's evidence cannot tell the two apart."
    )


def best_on_val(order: dict, prefix: str) -> str | None:
    """The name (after ``split/``) of the study's row best on val among those whose name starts with ``prefix``
    and which were run on test too; None where there is none."""
    return order_study.best_on_val(order, lambda k: k.startswith(prefix) and f"test/{k}" in order)


def known_albedo_reading(order: dict, geometry: str = "normal_pseudo", what: str = "pseudo geometry") -> str:
    """One sentence on what a geometry allows with the albedo's error removed: the known-albedo row on the
    ``geometry`` (a prefix of the rows' geometry names; ``what``: in words) best on val, with its val and test
    accuracy ("" where the study has no such row)."""
    best = best_on_val(order, f"known/{geometry}")
    if best is None:
        return ""
    rows = [order[f"{split}/{best}"] for split in ("val", "test")]
    val, test = (row["evidence"]["accuracy"] for row in rows)
    if min(val, test) < ORDER_TARGET:
        enough = "not expected to bring it to the target on both splits."
    elif any(target_inside(row["evidence"]["accuracy"], scenes(row)) for row in rows):
        enough = "enough, but only just: the target lies inside its 95 % interval."
    else:
        enough = "enough."
    return (
        f" With the true albedo on the same {what} (the known-albedo row best on val, `{best}`) the "
        f"choice reaches {val:.2f} on val and {test:.2f} on test: what the {what} allows once the albedo's "
        f"error is gone, so a better albedo model alone is {enough}"
    )


def uv_oracle_reading(order: dict, row: str = "texture/oracle_uv_network+geometry_noise") -> str:
    """One sentence on the networks' geometry with the true uv (an oracle row): whether the texture model, reaching
    the image through the true uv, brings the choice to the target on both splits ("" where the study lacks it)."""
    if not all(f"{split}/{row}" in order for split in ("val", "test")):
        return ""
    val, test = (order[f"{split}/{row}"]["evidence"]["accuracy"] for split in ("val", "test"))
    reached = min(val, test) >= ORDER_TARGET
    return (
        f" The texture model through the true uv on the explicit network's geometry (`{row}`, an oracle) reaches "
        f"{val:.2f} on val and {test:.2f} on test: "
        + (
            "the albedo model is good enough, and the uv through which it reaches the image is what stands between "
            "this geometry and the target."
            if reached
            else "even a true uv leaves the albedo model short of the target."
        )
    )


def target_inside(acc: float, n: int) -> bool:
    """Whether :data:`ORDER_TARGET` lies inside the 95 % interval of an accuracy ``acc`` over ``n`` scenes: then
    these scenes cannot tell the row from the target."""
    lo, hi = wilson_interval(acc, n)
    return lo <= ORDER_TARGET <= hi


def target_reading(acc: float, n: int) -> str:
    """Whether an accuracy ``acc`` over ``n`` scenes reaches :data:`ORDER_TARGET`, and whether the target lies
    outside its 95 % interval (the verdict holds beyond the sampling spread) or inside it (:func:`target_inside`)."""
    verdict = "**reached**" if acc >= ORDER_TARGET else "**not reached**"
    if target_inside(acc, n):
        return f"{verdict}, but the target lies inside its interval: these scenes cannot tell the row from the target"
    return f"{verdict}, the target {'below' if acc >= ORDER_TARGET else 'above'} its interval"


def paired_outcomes(order: dict, a: str, b: str) -> tuple[int, int, int] | None:
    """``(n, only_a, only_b)``: over the scenes that rows ``a`` and ``b`` (full keys, ``split/row``) both read (the
    same face at the same true order: the same image, noise included), how many, and on how many each one alone
    chose the order right; None where either lacks its scenes' outcomes."""
    outcomes = []
    for key in (a, b):
        rec = order.get(key, {}).get("scenes")
        if not rec:
            return None
        outcomes.append({(i, t): c == t for i, t, c in zip(rec["index"], rec["true_order"], rec["evidence"])})
    shared = outcomes[0].keys() & outcomes[1].keys()
    only_a = sum(outcomes[0][s] and not outcomes[1][s] for s in shared)
    only_b = sum(outcomes[1][s] and not outcomes[0][s] for s in shared)
    return len(shared), only_a, only_b


def mcnemar_p(only_a: int, only_b: int) -> float:
    """The exact two-sided McNemar p-value of paired outcomes: the discordant scenes, ``only_a`` against ``only_b``,
    as a binomial draw of even odds."""
    from scipy.stats import binomtest

    return 1.0 if only_a + only_b == 0 else float(binomtest(only_a, only_a + only_b, 0.5).pvalue)


def paired_reading(order: dict, split: str, a: str, b: str, name_b: str) -> str:
    """One clause: rows ``a`` and ``b`` (names after ``split/``) on the same scenes of ``split``, how many each one
    alone gets right and whether the difference is beyond chance (exact McNemar, 5 %); "" where either lacks its
    scenes' outcomes or they share none."""
    paired = paired_outcomes(order, f"{split}/{a}", f"{split}/{b}")
    if not paired or not paired[0]:
        return ""
    n, only_a, only_b = paired
    p = mcnemar_p(only_a, only_b)
    return (
        f"on the same {n} {split} scenes, {only_a} right only under it and {only_b} only under {name_b} (exact "
        f"McNemar p = {p:.2g}: {'beyond' if p < 0.05 else 'within'} chance)"
    )


def order_verdict(order: dict, prefix: str, what: str) -> tuple[str, str] | None:
    """``(row, sentence)``: among the study's rows whose name starts with ``prefix`` (on both splits), the one best
    on val, and its test accuracy against :data:`ORDER_TARGET` with a 95 % interval; None where there is no such
    row. ``what``: the geometry, in words."""
    chosen = best_on_val(order, prefix)  # the row chosen on val ...
    if chosen is None:
        return None
    test = order[f"test/{chosen}"]  # ... read on test
    acc, n = test["evidence"]["accuracy"], scenes(test)
    lo, hi = wilson_interval(acc, n)
    text = (
        f"Verdict, {what}, the row best on val (`{chosen}`, val {order[f'val/{chosen}']['evidence']['accuracy']:.2f}), "
        f"on test: {acc:.2f} (95 % interval {lo:.2f}-{hi:.2f} over its {n} scenes) against the target "
        f"{ORDER_TARGET:.2f}: {target_reading(acc, n)}. Over {n} scenes a split, "
        f"accuracies less than about {difference_spread((acc, n), (acc, n)):.2f} apart are within each other's "
        "sampling spread."
    )
    runner_up = best_on_val({k: v for k, v in order.items() if not k.endswith(f"/{chosen}")}, prefix)
    paired = [paired_reading(order, split, chosen, runner_up, "the runner-up") for split in ("val", "test")]
    if runner_up and all(paired):
        text += (
            f" Paired against the runner-up on val (`{runner_up}`, val "
            f"{order[f'val/{runner_up}']['evidence']['accuracy']:.2f}, test "
            f"{order[f'test/{runner_up}']['evidence']['accuracy']:.2f}): " + "; ".join(paired) + "."
        )
    return chosen, text


def placement_reading(order: dict) -> str:
    """One sentence on the coarse fit's placement under the residual process: refined against the image (its uv
    as drawn, or registered too), and made true (an oracle row), val/test accuracy, for the rows the study has on
    both splits; empty where it has fewer than two."""
    rows = {
        "refined against the image": "texture/normal_pseudo_placed+residual_process",
        "refined and its uv registered": "texture/normal_pseudo_placed_registered+residual_process",
        "made true (an oracle)": "texture/oracle_placement+residual_process",
    }
    rows = {text: row for text, row in rows.items() if all(f"{split}/{row}" in order for split in ("val", "test"))}
    if len(rows) < 2:
        return ""
    read = [
        f"{order[f'val/{row}']['evidence']['accuracy']:.2f}/{order[f'test/{row}']['evidence']['accuracy']:.2f} "
        f"({scenes(order[f'val/{row}'])}/{scenes(order[f'test/{row}'])} scenes) with it {text}"
        for text, row in rows.items()
    ]
    return (
        " The coarse fit's placement (pose, scale, shift) under the residual process, val/test accuracy: "
        + "; ".join(read)
        + "."
    )


def network_reading(order: dict, chosen: str, pseudo: str | None) -> str:
    """The ``chosen`` network row beside the ``pseudo`` geometry's chosen row on test: their accuracies, within or
    beyond the sampling spread, and how much band 2 each one's order-2 fit of a true order-1 scene holds, against
    the true order-2 lights' ("" where there is no pseudo row; the band-2 part where the study predates it)."""
    if not pseudo or f"test/{pseudo}" not in order:
        return ""
    ours, theirs = (order[f"test/{row}"] for row in (chosen, pseudo))
    gap = ours["evidence"]["accuracy"] - theirs["evidence"]["accuracy"]
    spread = difference_spread(*((r["evidence"]["accuracy"], scenes(r)) for r in (ours, theirs)))
    text = (
        f" The networks' normals are nearer the truth than the pseudo-GT's (claim 1), and on test the chosen row "
        f"scores {gap:+.2f} against the pseudo geometry's chosen row: "
        + (
            "within the sampling spread, so better normals alone do not bring the choice to the target."
            if abs(gap) < spread
            else "beyond the sampling spread, in the " + ("networks'" if gap > 0 else "pseudo geometry's") + " favour."
        )
    )
    if paired := paired_reading(order, "test", chosen, pseudo, "the pseudo geometry's row"):
        text += f" Paired, {paired}."
    if ours.get("band2_share") and theirs.get("band2_share"):
        text += (
            f" Its order-2 fit of a true order-1 scene holds {ours['band2_share']['fitted_by_true_order'][1]:.2f} in "
            f"band 2 ({theirs['band2_share']['fitted_by_true_order'][1]:.2f} on the pseudo geometry's); a true "
            f"order-2 light holds {ours['band2_share']['true_order2']:.2f}."
        )
    return text


YAW_BINS = (0.0, 15.0, 30.0, 45.0)  # |yaw| in degrees: SynthFaces draws yaw triangular within +-45, mostly near frontal


def face_attributes(order: dict, rows: list[str]) -> dict:
    """``{split: {attribute: labels [faces]}}``: the binary attribute labels of the SynthFaces faces that ``rows``'
    scene records (``scenes``) index, per split (the study's split and seed, 0 where a record predates its
    ``seed``)."""
    from disent.data import SynthFaces
    from disent.data.synth.scenes import attribute_labels

    out = {}
    for key, entry in order.items():
        split, row = key.split("/", 1)
        if row not in rows or not entry.get("scenes") or split in out:
            continue
        faces = list(range(max(entry["scenes"]["index"]) + 1))
        p = SynthFaces(split, seed=entry.get("settings", {}).get("seed", 0)).params(faces)
        out[split] = {a: label.numpy() for a, label in attribute_labels(p).items()}
    return out


def failure_bins(scenes: dict, labels: dict, names: list) -> dict:
    """A split's scenes binned by |yaw| (``YAW_BINS``), by thirds of the pixels fitted and by each attribute of
    ``names`` (``labels``: its per-face labels, none where absent): ``{bin: boolean mask over the scenes}``."""
    yaw, pixels = np.abs(scenes["yaw"]), np.array(scenes["pixels"])
    thirds = np.quantile(pixels, [1 / 3, 2 / 3])
    none = np.zeros(len(pixels), bool)
    return {
        **{f"yaw {lo:g}-{hi:g} deg": (yaw >= lo) & (yaw < hi) for lo, hi in zip(YAW_BINS, YAW_BINS[1:])},
        "fewest pixels": pixels <= thirds[0],
        "middle third": (pixels > thirds[0]) & (pixels <= thirds[1]),
        "most pixels": pixels > thirds[1],
        **{f"with {a}": np.asarray(labels[a], bool)[scenes["index"]] if a in labels else none for a in names},
    }


def failure_lines(order: dict, rows: list[str], attributes: dict | None = None) -> list[str]:
    """Where the order choice fails: for each of ``rows`` (names after ``split/``) read with each scene's outcome
    (``scenes``, :func:`disent.lighting.order_study.order_confusion`), its evidence accuracy by |yaw|, by the
    number of pixels fitted (thirds of the split's scenes) and on the faces with each attribute (``attributes``,
    :func:`face_attributes`; none where None), and a sentence per row on the bins whose accuracy differs from that
    of the split's other scenes beyond the sampling spread; no lines where no row has them."""
    names = sorted({a for labels in (attributes or {}).values() for a in labels})
    cells, notes = [], []
    for row in dict.fromkeys(rows):
        for split in ("val", "test"):
            scenes = order.get(f"{split}/{row}", {}).get("scenes")
            if not scenes:
                continue
            truth = np.array(scenes["true_order"])
            right = np.array(scenes["evidence"]) == truth
            bins = failure_bins(scenes, (attributes or {}).get(split, {}), names)
            acc, n = float(right.mean()), len(right)
            cells.append(
                f"| {split} | `{row}` | {acc:.2f} ({n}) | "
                + " | ".join(f"{right[b].mean():.2f} ({b.sum()})" if b.any() else "–" for b in bins.values())
                + " |"
            )

            def by_order(m):  # accuracy of the scenes ``m`` by true order 0/1/2
                return "/".join(
                    f"{right[m & (truth == k)].mean():.2f}" if (m & (truth == k)).any() else "–" for k in range(3)
                )

            beyond = [  # a bin against the split's other scenes (disjoint from it), and both by true order
                f"{name} ({right[b].mean():.2f} against {right[~b].mean():.2f}; by true order {by_order(b)} against "
                f"{by_order(~b)})"
                for name, b in bins.items()
                if b.any()
                and (~b).any()
                and abs(right[b].mean() - right[~b].mean())
                > difference_spread((right[b].mean(), b.sum()), (right[~b].mean(), (~b).sum()))
            ]
            notes.append(
                f"`{row}` on {split}: "
                + (
                    "no bin differs from the other scenes beyond the sampling spread"
                    if not beyond
                    else "beyond the sampling spread of the other scenes: " + ", ".join(beyond)
                )
            )
    if not cells:
        return []
    head = table_head(
        "split",
        "row",
        "all scenes",
        *(f"yaw {lo:g}-{hi:g} deg" for lo, hi in zip(YAW_BINS, YAW_BINS[1:])),
        "fewest pixels (a third)",
        "middle third",
        "most pixels (a third)",
        *(f"with {a}" for a in names),
    )
    return [
        "Where the chosen rows fail: evidence accuracy (scenes) by how far the face is turned (|yaw|, either way), "
        "by the number of pixels the fit sees (thirds of the split's scenes)"
        + (f" and on the faces labelled with each attribute ({', '.join(names)})" if names else "")
        + " (the three true orders pooled). A "
        "row's scenes are its faces each lit at the three orders, so a bin's scenes are not all independent: the "
        "spread below, which takes them as independent, is a lower bound. A bin beyond it is read by true order "
        "0/1/2 too, against the other scenes.\n",
        *head,
        *cells,
        "",
        "; ".join(notes) + ".\n",
    ]


def failure_figure_text(wrong: dict) -> str:
    """The caption of the figure of scenes the order choice got wrong (``order_failures.json``,
    :func:`disent.lighting.order_study.plot_order_failures`)."""
    scenes = "; ".join(
        f"face {s['index']}: true order {s['true_order']}, chosen {s['chosen']}, {s['evidence_gain']:+.0f}"
        for s in wrong["scenes"]
    )
    return (
        f"What `{wrong['row']}` fits where it fails: the first val scene of each kind of error, fitted again as the "
        f"study fitted it, with the chosen candidate's log evidence over the true order's best ({scenes}). "
        "Columns: the noisy image, the pixels fitted, the channel-mean residual of the true order's best candidate "
        "and of the chosen one, and their difference, which is what the chosen model's extra (or missing) SH terms "
        "fit. Regenerated by `python -m disent.lighting task=order` "
        "(`disent.lighting.order_study.plot_order_failures`).\n"
    )


def failure_region_lines(regions: dict) -> list[str]:
    """Where the misfit lies that makes the order choice fail (``order_failure_regions.json``,
    :func:`disent.lighting.order_study.order_failure_regions`, one entry per split): per split and kind of error, the
    share of the squared-residual reduction of the larger model in each part of the face beside the part's share of
    the fitted pixels, and the parts that take at least twice their share; no lines where there is none."""
    entries = [e for e in regions.values() if e.get("kinds")]
    if not entries:
        return []
    parts = list(next(iter(entries[0]["kinds"].values()))["pixel_share"])
    lines = [
        f"Where the misfit lies that makes `{entries[0]['row']}` fail: over every scene it gets wrong, fitted again, "
        "how much the larger of the two models (the true order's best candidate and the chosen one) lowers the "
        "squared residual in each part of the face, as a share of what it lowers in all; in brackets the part's "
        "share of the pixels fitted. The parts: the silhouette (within 2 px of the fitted region's border), then "
        "the eyes and brows, the nose and the mouth read from the scene's true uv "
        "(`disent.data.synth.face_model.FACE_REGIONS`), and the rest of the fit. Where the order is read too high, "
        "a part whose share of the reduction is well above its share of the pixels holds misfit that the extra SH "
        "terms absorb as light; where it is read too low, that part is where the terms turned down would have "
        "shown (`disent.lighting.order_study.order_failure_regions`).\n",
        *table_head("split", "error (true -> chosen order)", "scenes", *parts),
    ]
    above = []
    for entry in entries:
        for kind, k in entry["kinds"].items():
            true, chosen = kind.split("->")
            cells = [f"{k['reduction_share'][p]:.2f} ({k['pixel_share'][p]:.2f})" for p in parts]
            lines.append(f"| {entry['split']} | {true} -> {chosen} | {k['scenes']} | " + " | ".join(cells) + " |")
            twice = [p for p in parts if k["reduction_share"][p] >= 2 * k["pixel_share"][p]]
            if twice:
                above.append(f"{entry['split']} {true} -> {chosen}: {', '.join(twice)}")
    lines.append(
        "\nParts taking at least twice their share of the pixels: "
        + ("; ".join(above) if above else "none")
        + ". A negative share: there the larger model fits worse.\n"
    )
    return lines


def combined_reading(order: dict) -> str:
    """One sentence on the two noise models together: per geometry with a ``+geometry_noise+residual_process`` row on
    both splits, its val / test accuracy beside each model alone on the same geometry and albedo, and on how many
    geometries it beats each alone on val, where rows are chosen ("" where none)."""
    from disent.lighting.geometry import GEOMETRY

    both, cells, wins = "+geometry_noise+residual_process", [], 0
    for key in order:
        if not (key.startswith("val/") and key.endswith(both)) or f"test/{key[4:]}" not in order:
            continue
        row = key[4 : -len(both)]
        acc = {
            name: [order[f"{s}/{row}{suffix}"]["evidence"]["accuracy"] for s in ("val", "test")]
            for name, suffix in (
                ("both", both),
                ("geometry noise", "+geometry_noise"),
                ("residual", "+residual_process"),
            )
            if all(f"{s}/{row}{suffix}" in order for s in ("val", "test"))
        }
        alone = ", ".join(f"{v[0]:.2f}/{v[1]:.2f} {name} alone" for name, v in acc.items() if name != "both")
        label = GEOMETRY[row.split("/", 1)[1]].label
        cells.append(f"{acc['both'][0]:.2f}/{acc['both'][1]:.2f} on {label}" + (f" ({alone})" if alone else ""))
        wins += all(acc["both"][0] > v[0] for name, v in acc.items() if name != "both")
    if not cells:
        return ""
    return (
        "Both noise models together (the geometry noise for each pixel's variance, the residual process for how "
        "neighbours miss together), val/test accuracy: " + "; ".join(cells) + f". On val, where rows are chosen, "
        f"together beats each model alone on {wins} of {len(cells)} geometries.\n"
    )


# the inputs of a light in lhat_sources.json (disent.lighting.sources.lhat_sources), in words
LHAT_WORDS = {
    "normal_pseudo": "N-hat",
    "normal": "**true**",
    "constant": "constant (the paper's)",
    "template": "placed mean texture",
    "texture_model": "texture model, fitted with L",
    "albedo": "**true**",
    "mask_pseudo": "M-hat",
    "eroded": "M-hat eroded 1 px",
    "face": "**true face** inside M-hat",
    "network": "the network's",
    "matte": "M-hat inside its matte",
    "eroded_matte": "M-hat eroded 1 px inside its matte",
    "-": "–",
}


def lhat_source_name(key: str) -> str:
    """A light of ``lhat_sources.json`` in words: L-hat, an oracle dose, a shipped network's own light, or the constant
    light."""
    if key == "floor":
        return "constant light (the mean train light; the floor)"
    if key == "lhat_eroded":
        return "L-hat (`loss.recon_L_target=sh_pseudo_eroded`)"
    if key == "texture_model_lhat_scale":
        return "L-hat at L-hat's per-face scale (`loss.recon_L_scale=sh_pseudo`)"
    if key.startswith("oracle_mix_"):
        share = key.rsplit("_", 1)[1]
        return f"L-hat moved {share} of the way to the true light (`loss.recon_L_oracle_mix={share}`)"
    if key.startswith("network_"):
        name = key.split("_")[1]
        if key.endswith("_texture"):
            return f"{name} network's light and the texture model through its geometry (`sh_network_texture`)"
        return f"{name}: least squares over its albedo" if key.endswith("_refit") else f"{name} network's light"
    return "L-hat" + (" (the paper's E_recon-L target, Eq. 9)" if key == "lhat" else "")


def contrast_cell(row: dict) -> str:
    """A light's contrast against the truth's, with its pattern and magnitude where the row has them."""
    parts = [row.get(k) for k in ("pattern_corr", "contrast_ratio")]
    extra = f" ({parts[0]:.2f}, {parts[1]:.2f})" if None not in parts else ""
    return fmt_value(row.get("contrast"), ".2f") + extra


def contrast_reading(name: str, row: dict, lhat: dict) -> str:
    """How ``row``'s light's contrast differs from L-hat's (``lhat``), part by part: pattern and magnitude."""

    def compared(key, more, less, same):
        x, y = row[key], lhat[key]
        return f"{more if x > y + 0.005 else less if x < y - 0.005 else same} ({x:.2f} against {y:.2f})"

    pattern = compared("pattern_corr", "a better pattern", "a worse pattern", "the same pattern")
    magnitude = compared("contrast_ratio", "more magnitude", "less magnitude", "as much magnitude")
    contrast = f"contrast {row['contrast']:.2f} against {lhat['contrast']:.2f}"
    if None not in (row.get("log_error"), lhat.get("log_error")):
        contrast += f", log error {row['log_error']:.3f} against {lhat['log_error']:.3f}"
    return f"{name} has {pattern} and {magnitude} than L-hat's: {contrast}"


def sharpening_lines(rows: dict) -> list[str]:
    """What a more or less contrasty shading would give each shipped network's albedo (``lhat_sources.json``'s
    ``sharpened_albedo``), with the network's calibration about its target: the table and its reading."""
    nets = {k.split("_")[1]: r for k, r in rows.items() if "sharpened_albedo" in r}
    if not nets:
        return []
    ks = list(next(iter(nets.values()))["sharpened_albedo"])
    lines = [
        "\nWhy a network's light is flatter than its target, and whether more contrast would help. *Calibration*: "
        "the slope of L-hat's log shading on the network's light's, through N-hat on M-hat (no truth), the median "
        "over faces and channels: 1 where the network is right on average about its target, what a least-squares "
        "fit gives when it cannot tell all of the target from the image; it is then flatter than the target by "
        "what it cannot tell. The other columns take the network's own shading S (its normals and light) to the "
        "power k, its log contrast times k, and score the detailed albedo of Sec. 5.3, the image over S^k, against "
        "the true albedo (si-MSE, scored pixels; `disent.lighting.sources.sharpened_albedo`): k = 1 is the "
        "shading as it is, k > 1 more contrasty.\n",
        *table_head("network", "calibration", *(f"k = {k}" for k in ks)),
    ]
    for name, r in nets.items():
        cells = " | ".join(f"{v:.5f}" for v in r["sharpened_albedo"].values())
        lines.append(f"| {name} | {fmt_value(r.get('calibration'), '.2f')} | {cells} |")
    best = {n: min(r["sharpened_albedo"], key=r["sharpened_albedo"].get) for n, r in nets.items()}
    gain = {n: 1 - r["sharpened_albedo"][best[n]] / r["sharpened_albedo"][str(1.0)] for n, r in nets.items()}
    calibrated = ", ".join(f"{n} {fmt_value(r.get('calibration'), '.2f')}" for n, r in nets.items())
    sharper = [n for n in nets if float(best[n]) > 1.0 and gain[n] > 0.01]
    lines.append(
        f"\nCalibration about L-hat: {calibrated}. The detailed albedo is best at k = "
        + ", ".join(f"{best[n]} for {n}" + (f" ({gain[n]:.1%} below k = 1)" if gain[n] else "") for n in nets)
        + (
            f": a more contrasty shading would help {' and '.join(sharper)}'s albedo.\n"
            if sharper
            else ": the networks' shading is as contrasty as its pattern allows, and more contrast would not help "
            "the albedo; what the light lacks is its pattern (the first part of the contrast column), not its "
            "magnitude.\n"
        )
    )
    return lines


def lhat_source_lines(src: dict) -> list[str]:
    """Where L-hat's error on the face comes from (``lhat_sources.json``): the table and its reading."""
    rows = src["rows"]
    e = {k: r["light_on_face"] for k, r in rows.items()}
    lines = [
        "### Where L-hat's error comes from\n",
        "L-hat, the least-squares light of Eq. 9 (`disent.render.fit_sh_packed`), fitted with its inputs "
        "made true one at a time: first its pixels (M-hat also covers some hair, ears and background), then from there "
        "the normals, the albedo (or in its place a placed mean texture: the mean train albedo in UV space through the "
        "pseudo uv), or both; beside them what needs no truth: M-hat eroded, the PCA texture model fitted with the "
        "light (`disent.lighting.targets.texture_lhat`; E_recon-L's target under "
        "`loss.recon_L_target=sh_texture`), the shipped networks' own light, and the least-squares "
        "light of the image over a network's own albedo. *Light on the face*: its shading through the true normals "
        "against the true light's, scale-invariant per image and channel, on the scored pixels (the networks' "
        "*light on the face* in the glance section), mean ± standard error over the faces; *beats L-hat*: the share "
        f"of faces where it is below the paper's L-hat; *shown SH error*: along the SH directions the face shows; "
        "*skin in its shading*: the correlation over faces of its shading's mean chromaticity (tone) and luminance "
        "(brightness) on the scored pixels with the true albedo's (`disent.eval.scoring.skin_in_shading`, as "
        "`shading_albedo_tone_corr` scores the networks' shading), the per-face scale that *light on the face* is "
        "blind to and that a light hands on to the albedo; the true light's is about 0; *contrast*: the median over "
        "faces and channels of the slope of its log shading on the true light's, on the scored pixels "
        "(`disent.eval.metrics.shading_contrast`; 1: the truth's contrast at any scale, below 1: the rest of the "
        "shading left to the albedo), and in brackets the two parts of that slope (`disent.eval.metrics."
        "log_shading_agreement`): the *pattern*, the correlation of its log shading with the truth's, and the "
        "*magnitude*, the ratio of their spreads (the slope is pattern x magnitude, face by face); *log error*: what "
        "both leave wrong, the squared difference of the centred log shadings as a share of the truth's spread, "
        "1 - 2 pattern x magnitude + magnitude^2 face by face (0: the truth's up to scale; the error an albedo, the "
        "image over this shading, inherits), the median over faces and channels. "
        f"The first {src['n']} {src['split']} images, noise-free as training sees them "
        "(`python -m disent.lighting task=lhat`; `disent.lighting.sources.lhat_sources`).\n",
        *table_head(
            "light",
            "normals",
            "albedo",
            "pixels",
            "light on the face",
            "beats L-hat",
            "shown SH error",
            "skin in its shading (tone / brightness)",
            "contrast (pattern, magnitude)",
            "log error",
        ),
    ]
    for k, r in rows.items():
        words = " | ".join(LHAT_WORDS.get(i, i) for i in r["inputs"])
        skin = " / ".join(fmt_value(r.get(f"skin_{c}_corr"), "+.2f") for c in ("tone", "brightness"))
        lines.append(
            f"| {lhat_source_name(k)} | {words} | {r['light_on_face']:.4f} ± {r['light_on_face_se']:.4f} | "
            f"{r['beats_lhat']:.2f} | {r['shown']:.3f} | {skin} | {contrast_cell(r)} | "
            f"{fmt_value(r.get('log_error'), '.3f')} |"
        )
    if not {"lhat", "true_pixels", "true_pixels_normals", "true_pixels_albedo"} <= set(e):
        return lines + [""]
    return lines + [lhat_source_reading(rows) + "\n", *sharpening_lines(rows)]


def lhat_source_reading(rows: dict) -> str:
    """What the L-hat source table says: which of L-hat's inputs costs it most, the best light without truth
    against the networks' own, and the skin every light fitted without the true albedo keeps."""
    e = {k: r["light_on_face"] for k, r in rows.items()}
    larger = "albedo" if e["true_pixels_albedo"] < e["true_pixels_normals"] else "normals"
    reading = (
        f"\nThe paper's L-hat misses the light on the face by {e['lhat']:.4f} (the constant light: "
        f"{e.get('floor', float('nan')):.4f}). The true pixels take it to {e['true_pixels']:.4f}; from there the true "
        f"normals to {e['true_pixels_normals']:.4f} and the true albedo to {e['true_pixels_albedo']:.4f}: L-hat's "
        f"{'constant albedo costs' if larger == 'albedo' else 'coarse-fit normals cost'} it more than its "
        f"{'coarse-fit normals' if larger == 'albedo' else 'constant albedo'}."
    )
    free = {k: e[k] for k in ("lhat_eroded", "texture_model") if k in e}
    nets = {k.split("_")[1]: v for k, v in e.items() if k.startswith("network_") and k.count("_") == 1}
    if free and nets:
        best = min(free, key=free.get)
        below = all(v < free[best] for v in nets.values())
        reading += (
            f" Without truth, the best L-hat here is {'the texture model' if best == 'texture_model' else 'eroded'}"
            f" ({free[best]:.4f}); the networks' own light ({', '.join(f'{n} {v:.4f}' for n, v in nets.items())}) is "
            + ("below it: trained on the paper's L-hat, the networks go beyond it" if below else "not below it")
        )
        refits = {n: e[f"network_{n}_refit"] for n in nets if f"network_{n}_refit" in e}
        if refits and all(refits[n] >= nets[n] for n in refits):
            reading += (
                ", and the least-squares light over a network's own albedo does not improve on the network's ("
                + ", ".join(f"{n} {v:.4f}" for n, v in refits.items())
                + ")"
            )
        if mixed := {n: e[f"network_{n}_texture"] for n in nets if f"network_{n}_texture" in e}:
            nearer = all(mixed[n] < min(nets[n], free[best]) for n in mixed)
            reading += (
                "; averaged with the texture model's refit through its own normals and uv (`sh_network_texture`), "
                f"a network's light {'gets nearer than either' if nearer else 'gets no nearer than both'} ("
                + ", ".join(f"{n} {v:.4f}" for n, v in mixed.items())
                + ")"
            )
        reading += "."
    for k, name in (("lhat_eroded", "L-hat on M-hat eroded 1 px"), ("texture_model", "The texture model's light")):
        if k in rows and None not in (rows[k].get("pattern_corr"), rows["lhat"].get("pattern_corr")):
            reading += " " + contrast_reading(name, rows[k], rows["lhat"]) + "."
    fitted = [r for r in rows.values() if r["inputs"][1] not in ("albedo", "-") and "skin_tone_corr" in r]
    if fitted:
        tone, bright = ([r[f"skin_{c}_corr"] for r in fitted] for c in ("tone", "brightness"))
        reading += (
            f" Every light here fitted without the true albedo keeps each face's skin in its shading (tone "
            f"{min(tone):+.2f} to {max(tone):+.2f}, brightness {min(bright):+.2f} to {max(bright):+.2f} over faces, "
            "the networks' own included): the skin's scale and the light's are one unknown in the image, and a "
            "target that carries the skin teaches it to Z_L."
        )
    return reading


def sec_lighting(rep: Report, out: Path) -> None:
    """How uncertain L-hat is and which lighting order a scene needs, from ``reports/lighting/*.json``."""
    d = out / "lighting"
    order, cal, cal_p, speed, sources = (
        load_json(d / f"{n}.json") for n in ("order", "calibration", "calibration_pseudo", "speed", "lhat_sources")
    )
    if not (order or cal or speed or sources):
        rep.note("`reports/lighting/`; run `python -m disent.lighting task=report`, then publish its folder.")
        return
    rep.add(
        "Regenerate: `python -m disent.lighting task=report` (one core: one torch and one OpenBLAS thread), then "
        "`python -m disent.report --publish OUTPUT_FOLDER`. SynthFaces 64x64; i.i.d. Gaussian noise, std 0.02, "
        "added to each image. Sampler: emcee with an independence proposal (`disent/lighting/posterior.py`).\n"
    )
    if sources:
        rep.add(*lhat_source_lines(sources))
    if order:
        lighting_order_table(rep, d, order)
        lighting_order_readings(rep, d, order)
    if cal or cal_p:
        lighting_calibration(rep, d, cal or {}, cal_p or {})
    for name in ("widths", "example_corner", "example_shading_sd"):
        if (d / f"{name}.png").exists():
            rep.image(d / f"{name}.png", name)
    if speed:
        lighting_speed(rep, speed)


def order_caption(d: Path) -> str:
    """What the order study's table holds: its candidates, albedos, geometries and noise models."""
    return (
        "Item *i* of the split relit with its own light cut to SH order 0, 1 or 2, 20 scenes per order (a row "
        "read again with more, as the rows the verdicts compare are, has them in its confusion counts). "
        "Candidates: order 0, order 1 and 2 in gray or RGB; the smallest model within log 20 of the best "
        "Laplace evidence is chosen (BIC beside it). *Albedo*: known (the reference), constant (what L-hat "
        "assumes), or a PCA texture model fitted with the light (`disent/lighting/texture.py`). *Geometry "
        "noise*: each pixel's variance adds what a normal error of std `normal_sigma` (the geometry's "
        "measured mean error read as an isotropic tangent Gaussian: the pseudo-GT's, or a network row's model's "
        "own test error; not fitted here) does to it under the candidate's light "
        "(`select_order(..., normal_sigma=...)`, `disent.lighting.order_study.geometry_noise`). *Residual "
        "process*: the misfit is "
        "spatially correlated, noise covariance sigma^2 (I + rho exp(-d / ell)) / (1 + rho) over pixel distance "
        "d, with rho and ell by maximum likelihood on train scenes' residuals at their true light "
        f"({residual_text(d)}; `select_order(..., residual=(rho, ell))`). *Geometry noise and residual "
        "process*: both, each channel's covariance V^1/2 R V^1/2 with R the residual process's correlation and V "
        "each pixel's variance under the geometry noise: the geometry says how far each pixel may miss, the "
        "residual process how neighbours miss together (rho and ell fitted with the geometry noise beside them). "
        "*Eroded mask*: the pseudo mask less "
        "its edge pixels, where the coarse fit's normals graze and its silhouette leaks onto hair or background "
        "(`disent.lighting.geometry.GEOMETRY`). *uv registered*: the pseudo uv corrected by the affine map "
        "that best registers the texture model to the image, found before any candidate is scored (Gauss-Newton "
        "on the six affine parameters, the light and texture fitted again at each step, coarse to fine, under a "
        "Gaussian prior of the affine maps that take train scenes' pseudo uv onto their true uv; "
        "`disent.lighting.texture.register`). *Placement refined*: the coarse fit's maps rendered again at its "
        "pose, scale and shift refined against the image, its shape kept: Powell's method on the fit of the "
        "texture model and an order-2 RGB light to the coarse fit's mask eroded 3 px, under a Gaussian prior of "
        "the coarse fit's placement errors on train scenes (`disent.lighting.geometry.refine_placement`); with "
        "*uv registered* too, the refined maps' uv then registered as above. "
        "*Oracle* rows put one true layer into the pseudo geometry, "
        "to say which of its errors costs the choice: the true uv (the texture model registered to the face) "
        "or the true normals, or on the explicit network's geometry the true uv "
        "(`disent.lighting.geometry.GEOMETRY`). *Network* rows take the normals and matte "
        "(eroded 1 px) that a shipped model (`disent/weights/`), trained on the pseudo-GT alone, draws from the "
        "scene's noisy image, with the pseudo uv registered (explicit; in the `network_explicit_placed` row the "
        "uv of the coarse fit placed against the image, then registered) or the model's own uv (implicit; in the "
        "*uv registered* row corrected under the prior of that uv's affine errors on train scenes, "
        "`registration_prior(network=...)`): a "
        "geometry with no ground truth in it, whose normals beat the pseudo-GT's (claim 1; "
        "`disent.lighting.texture.network_maps`). *Band 2 fitted*: the median over a true "
        "order's scenes of what the largest candidate (order 2, RGB) puts in SH band 2, as a share of bands 0 "
        "and 1 (`disent.lighting.order.band2_share`), beside the true order-2 lights' median: where an order-1 "
        "scene's fit holds as much band 2 as a true order-2 light, the geometry's error shows as band-2 light "
        "and no criterion built on the fit can tell the two orders apart. Constants were chosen on val; test "
        "only reports; the order study alone: `python -m disent.lighting task=order`; some of its rows, the "
        "others kept as published: `python -m disent.lighting task=order order_rows='[ALBEDO/GEOMETRY+NOISE]' "
        "order_keep=reports/lighting`. The order choice of `python -m disent.lighting image=PHOTO` takes the noise "
        "model of the row best on val for its albedo and geometry (`order_noise=auto`).\n"
    )


def lighting_order_table(rep: Report, d: Path, order: dict) -> None:
    """The order study's table: each split, albedo and geometry's confusion and accuracy, and its band-2 share."""
    from disent.lighting.geometry import GEOMETRY

    rep.add(
        "### Lighting model order: model no more than a scene needs\n",
        order_caption(d),
        *table_head(
            "split",
            "albedo",
            "geometry",
            "evidence confusion (rows: true order 0, 1, 2)",
            "evidence acc.",
            "BIC acc.",
            "band 2 fitted, true order 0 / 1 / 2 (true order-2 lights)",
        ),
    )
    for key, r in order.items():
        split, albedo, geometry = key.split("/", 2)
        normals, _, noise = geometry.partition("+")
        geometry = GEOMETRY[normals].label + (f", {noise.replace('_', ' ').replace('+', ' and ')}" if noise else "")
        ev, bic = r["evidence"], r["bic"]
        band2 = r.get("band2_share")  # studies written before it was measured have none
        band2 = (
            " / ".join(f"{v:.2f}" for v in band2["fitted_by_true_order"]) + f" ({band2['true_order2']:.2f})"
            if band2
            else "–"
        )
        rep.add(
            f"| {split} | {albedo} | {geometry} | {ev['confusion']} | {_pct(ev['accuracy'])} | "
            f"{_pct(bic['accuracy'])} | {band2} |"
        )


def lighting_order_readings(rep: Report, d: Path, order: dict) -> None:
    """What the order study's rows say: the verdicts without the true albedo, where the choice fails, which error
    of the pseudo geometry costs it, and its figures."""
    pseudo = order_verdict(order, "texture/normal_pseudo", "pseudo geometry without the true albedo")
    if pseudo:
        rep.add(
            "",
            pseudo[1] + band2_reading(order, pseudo[0]) + known_albedo_reading(order) + placement_reading(order) + "\n",
        )
    network = order_verdict(
        order,
        "texture/network_",
        "the networks' geometry without the true albedo (the normals and matte that a shipped model trained on "
        "the pseudo-GT alone draws from the image, with the implicit model's own uv or the coarse fit's)",
    )
    if network:
        rep.add(
            "",
            network[1]
            + network_reading(order, network[0], pseudo and pseudo[0])
            + known_albedo_reading(order, "network_", "networks' geometry")
            + uv_oracle_reading(order)
            + "\n",
        )
    if combined := combined_reading(order):
        rep.add(combined)
    chosen = [row for row, _ in filter(None, (pseudo, network))]
    if failures := failure_lines(order, chosen, face_attributes(order, chosen)):
        rep.add(*failures)
    if (wrong := load_json(d / "order_failures.json")) and (d / "order_failures.png").exists():
        rep.add(failure_figure_text(wrong))
        rep.image(d / "order_failures.png", "order_failures")
    rep.add(*failure_region_lines(load_json(d / "order_failure_regions.json") or {}))
    rows = {
        "normal_pseudo_eroded": "on the pseudo geometry",
        "normal_pseudo_registered": "with its uv registered to the image",
        "normal_pseudo_placed": "with its placement refined against the image",
        "oracle_uv": "with only its uv made true",
        "oracle_normals": "with only its normals made true",
        "oracle_placement": "with the coarse fit's placement (pose, scale, shift) made true",
        "oracle_shape": "with the coarse fit's shape (identity, expression) made true",
    }
    accuracy = {  # the oracle rows and the pseudo geometry they start from, texture model, i.i.d. noise
        (split, k): order[f"{split}/texture/{k}"]["evidence"]["accuracy"]
        for split in ("val", "test")
        for k in rows
        if f"{split}/texture/{k}" in order
    }
    rows = {k: text for k, text in rows.items() if ("val", k) in accuracy and ("test", k) in accuracy}
    if "normal_pseudo_eroded" in rows and any(k.startswith("oracle") for k in rows):
        oracles = [k for k in rows if k.startswith("oracle")]
        reached = [k for k in oracles if accuracy["test", k] >= ORDER_TARGET]
        rep.add(
            "Where the pseudo geometry's error comes from (texture model, i.i.d. noise, val/test accuracy): "
            + ", ".join(f"{accuracy['val', k]:.2f}/{accuracy['test', k]:.2f} {text}" for k, text in rows.items())
            + ". "
            + (
                f"Made true alone, {' and '.join(reached)} reaches the target on test.\n"
                if reached
                else "Nothing made true alone brings the test accuracy to the target; the largest gain (val and "
                f"test together) comes {rows[max(oracles, key=lambda k: accuracy['val', k] + accuracy['test', k])]}"
                ".\n"
            )
        )
    if (d / "order_accuracy.png").exists():
        rep.add(
            "Every row's evidence accuracy on val (open) and test (filled), with its 95 % interval over the row's "
            "scenes (Wilson), against the target and against choosing one order for every scene (1/3); the "
            "confusion matrices are in the table above (`disent.lighting.order_study.plot_order_accuracy`).\n"
        )
        rep.image(d / "order_accuracy.png", "order_accuracy")
    if (registration := load_json(d / "registration.json")) and (d / "registration.png").exists():
        rep.add(
            "The texture model fitted through the pseudo, registered and true uv on val scenes under order-1 "
            f"light (`disent.lighting.order_study.plot_registration`); uv error, rms per axis over the shown "
            f"scenes: {registration['normal_pseudo_eroded']:.1f} px pseudo, "
            f"{registration['normal_pseudo_registered']:.1f} px registered.\n"
        )
        rep.image(d / "registration.png", "registration")


def lighting_calibration(rep: Report, d: Path, cal: dict, cal_p: dict) -> None:
    """The posterior's coverage of the true SH coefficients, with the true and the pseudo geometry."""
    rep.add(
        "### Calibration of the posterior\n",
        "Known albedo; share of the true SH coefficients inside the 68 % and 95 % credible intervals "
        "(a calibrated posterior: 0.68 and 0.95) and the RMS of their z-scores (calibrated: 1), with "
        "effects at severity 0.5.\n",
        *table_head(
            "condition / likelihood",
            "true normals: 68 % / 95 % (z-RMS)",
            "pseudo normals + mask: 68 % / 95 % (z-RMS)",
        ),
    )
    for key in dict.fromkeys(k for c in (cal, cal_p) for k, v in c.items() if isinstance(v, dict) and "inside68" in v):
        cells = [
            f"{_pct(c[key]['inside68'])} / {_pct(c[key]['inside95'])} ({c[key]['z_rms']:.1f})" if key in c else "–"
            for c in (cal, cal_p)
        ]
        rep.add(f"| {key.replace('/', ' / ')} | {cells[0]} | {cells[1]} |")
    rep.add("")
    for name in ("calibration", "calibration_pseudo"):
        if (d / f"{name}.png").exists():
            rep.image(d / f"{name}.png", name)


def lighting_speed(rep: Report, speed: dict) -> None:
    rep.add(
        "### Speed\n",
        f"One core, test item 0 ({speed['n_pixels']} face pixels): L-hat by least squares "
        f"{speed['ls_ms_per_image']:.2f} ms per image (batch {speed['ls_batch']}); the posterior "
        f"{speed['posterior_gaussian_s']:.2f} s with a Gaussian likelihood "
        f"({speed['posterior_gaussian_steps']:.0f} "
        f"steps), {speed['posterior_student_t_s']:.2f} s with Student-t ({speed['posterior_student_t_steps']:.0f} "
        "steps)"
        + (
            "; the order choice without the true albedo (texture model, residual process), median of test items "
            f"0-{speed['order_choice_items'] - 1}: "
            + ", ".join(f"{s:.1f} s on `{g}`" for g, s in speed["order_choice_s"].items())
            if speed.get("order_choice_s")
            else ""
        )
        + ". Also `python -m disent.bench lighting`.\n",
    )
