"""The run catalogue (disent.runs) on tiny fake run folders: labels, settings, status, picking runs."""

import json
import subprocess
from pathlib import Path

import pytest
import yaml

from disent.images import pyplot
from disent.report import document, tables
from disent.runs import Run, composed_config, find_runs, group_by_setting, measured_setting, pick_runs
from tests.run_fakes import fake_suite, make_run


def test_run_labels_and_status(tmp_path):
    fake_suite(tmp_path)
    runs = {r.path.name: r for r in find_runs([tmp_path])}
    assert len(runs) == 7
    assert runs["3"].variant == "explicit+no_bws" and runs["4"].ablations == ["no_adv"] and not runs["4"].adversarial
    assert [runs[k].status for k in "0123456"] == ["ok", "ok", "ok", "ok", "nan", "diverged", "incomplete"]
    assert runs["1"].value("normal_mean") == 20.0 and runs["1"].value("images_per_s") == 500.0


def test_contents_links_each_section_by_githubs_heading_anchor():
    """GitHub's anchors: punctuation dropped, spaces made hyphens, a repeated heading numbered; the claims'
    subsections listed under their section, no other section's; headings inside code blocks are not headings."""
    md = "\n".join(
        [
            "# disent report",
            "## The paper's claims, measured",
            "### 1. The network's normals go beyond the fit",
            "## Benchmarks (`reports/bench*.json`)",
            "### (defaults)",
            "```",
            "## not a heading",
            "```",
            "## Ablations",
            "### (defaults)",
        ]
    )
    assert document.contents(md, open_sections=("The paper's claims, measured",)) == [
        "**Contents**\n\n"
        "- [The paper's claims, measured](#the-papers-claims-measured)\n"
        "  - [1. The network's normals go beyond the fit](#1-the-networks-normals-go-beyond-the-fit)\n"
        "- [Benchmarks (`reports/bench*.json`)](#benchmarks-reportsbenchjson)\n"
        "- [Ablations](#ablations)\n"
    ]
    seen = {}
    assert [document.heading_anchor("(defaults)", seen) for _ in range(3)] == ["defaults", "defaults-1", "defaults-2"]


def test_run_status_callback_marks_nan(tmp_path):
    from hydra.core.utils import JobReturn, JobStatus
    from omegaconf import OmegaConf

    from disent.runs import RunStatus

    d = make_run(tmp_path, "r", losses=(1.0, 0.5))  # the log itself looks healthy
    hydra_cfg = OmegaConf.create({"hydra": {"runtime": {"output_dir": str(d)}}})
    ret = JobReturn(
        hydra_cfg=hydra_cfg,
        status=JobStatus.FAILED,
        _return_value=FloatingPointError("loss term 'BWS' is not finite at step 3"),
    )
    RunStatus().on_job_end(None, ret)
    assert Run.load(d).status == "nan"
    ret = JobReturn(hydra_cfg=hydra_cfg, status=JobStatus.FAILED, _return_value=RuntimeError("out of memory"))
    RunStatus().on_job_end(None, ret)
    assert Run.load(d).status == "failed"


def test_pick_runs_prefers_the_longest_trained_run(tmp_path):

    short = make_run(tmp_path, "short", "explicit", seed=0, eval_={"steps": 30})
    long = make_run(tmp_path, "long", "explicit", seed=1, eval_={"steps": 700})
    ablated = make_run(tmp_path, "abl", "explicit", ["no_bws"], seed=0, eval_={"steps": 900})
    for d in (short, long, ablated):
        (d / "checkpoints").mkdir()
        (d / "checkpoints" / "last.pt").write_bytes(b"")
    chosen = pick_runs(find_runs([tmp_path]))
    assert set(chosen) == {"explicit"} and chosen["explicit"].path.name == "long"


def test_claim_verdicts_need_seeds_and_a_difference_beyond_the_spread():
    from disent.report.tables import MIN_SEEDS, verdict

    n = MIN_SEEDS
    arm = lambda mean, std, k=n: {"mean": mean, "std": std, "n": k}  # noqa: E731  (what tables.seed_spread returns)
    assert verdict(arm(10.0, 0.2), arm(11.5, 0.0), "lower") == "**confirmed**"
    assert verdict(arm(12.0, 0.2), arm(11.5, 0.0), "lower") == "**refuted**"
    assert verdict(arm(11.4, 0.3), arm(11.5, 0.0), "lower").startswith("not resolved")
    assert verdict(arm(27.0, 0.1), arm(24.0, 0.1), "higher") == "**confirmed**"
    assert verdict(arm(10.0, 0.0, 1), arm(11.5, 0.0), "lower").startswith("not testable (1 seed")
    assert verdict(None, arm(11.5, 0.0), "lower").startswith("not testable")


def test_captions_name_the_machines_the_runs_trained_on(tmp_path):
    a, b = make_run(tmp_path, "a", eval_={}), make_run(tmp_path, "b", eval_={})
    info = {"processor": "x86_64", "cpus": 2, "torch": "2.13.0+cpu", "device": "cpu", "threads": 1}
    (a / "machine.json").write_text(json.dumps(info))
    runs = find_runs([tmp_path])
    assert tables.machines(runs) == (
        "x86_64, 2 CPUs, torch 2.13.0+cpu, device cpu, 1 thread(s) (1 run(s) from before machines were recorded)"
    )
    assert tables.machines([r for r in runs if r.path == b]) == "not recorded"


def test_setting_is_what_one_types_today_to_train_the_run_again(tmp_path):
    """A run's setting: its config-group choices and each defining value that differs from today's conf/, so that
    a run trained before a default changed is told apart from one trained after, however it was typed."""
    from disent.config import ADDED_LATER
    from disent.runs import setting

    today = composed_config(("model=explicit",))
    lr = today["train"]["lr"]
    make_run(tmp_path, "a", extra=[f"train.lr={lr}"])  # an override that repeats today's default is none
    b = make_run(tmp_path, "b")  # trained under other defaults: another lr, before loss.recon_fg_p existed
    cfg = yaml.safe_load((b / ".hydra" / "config.yaml").read_text())
    cfg["train"].update(lr=10 * lr, threads=7)  # threads do not define a run
    del cfg["loss"]["recon_fg_p"]
    (b / ".hydra" / "config.yaml").write_text(yaml.safe_dump(cfg))
    make_run(tmp_path, "c", "implicit", ["no_bws"], extra=["+experiment=smoke"])
    runs = {r.path.name: r for r in find_runs([tmp_path])}
    assert setting(runs["a"]) == "model=explicit" and setting(runs["a"], drop_model=True) == "(defaults)"
    before = ADDED_LATER["loss.recon_fg_p"]
    expected = ([f"loss.recon_fg_p={before}"] if before != today["loss"]["recon_fg_p"] else []) + [
        "model=explicit",
        f"train.lr={10 * lr}",
    ]
    assert setting(runs["b"]) == " ".join(expected)
    assert setting(runs["c"]) == "+ablation=[no_bws] +experiment=smoke model=implicit"
    assert setting(runs["c"], drop_model=True, drop=("ablation=",)) == "+experiment=smoke"
    # a tool's record of a run (edit.json, sh_variance.json) is read with the setting of today's conf/
    stale = {"run": str(b), "setting": "(defaults)"}
    assert measured_setting(stale) == setting(runs["b"], drop_model=True) != "(defaults)"
    assert measured_setting({"run": str(tmp_path / "gone"), "setting": "(defaults)"}) is None  # stale
    assert measured_setting({"run": "explicit", "setting": "shipped"}) == "shipped"


def test_bws_c_is_not_part_of_a_run_that_neither_uses_bws_nor_whitens_lhat(tmp_path):
    """c acts through BWS and the whitened L-hat target: a run with both off (``+ablation=no_bws``) trains the same
    under any c, and a run with either on does not (:func:`disent.train.idle_settings`)."""
    from disent.config import idle_settings
    from disent.runs import setting

    for name, bws, white in (("no_bws", 0.0, False), ("bws_off_white", 0.0, True), ("raw", 1.0, False)):
        d = make_run(tmp_path, name, "explicit")
        cfg = yaml.safe_load((d / ".hydra" / "config.yaml").read_text())
        cfg["loss"]["weights"]["BWS"], cfg["loss"]["lhat_white"] = bws, white
        cfg["loss"]["bws_c"] = 0.3
        (d / ".hydra" / "config.yaml").write_text(yaml.safe_dump(cfg))
    runs = {r.path.name: r for r in find_runs([tmp_path])}
    assert "loss.bws_c" in idle_settings(runs["no_bws"].cfg)
    assert "loss.bws_c=" not in setting(runs["no_bws"])
    for name in ("bws_off_white", "raw"):
        assert "loss.bws_c" not in idle_settings(runs[name].cfg) and "loss.bws_c=0.3" in setting(runs[name])


def test_a_loss_weight_the_model_has_no_term_for_is_not_part_of_its_setting(tmp_path):
    """The baseline has no normals: a run of it trained under another E_recon-N weight (or the masked
    reconstruction's norm) is the same setting as today's; the explicit model's is not."""
    from disent.runs import setting

    for model in ("baseline", "explicit"):
        d = make_run(tmp_path, model, model)
        cfg = yaml.safe_load((d / ".hydra" / "config.yaml").read_text())
        cfg["loss"]["weights"]["recon_N"] += 1.0
        cfg["loss"]["recon_fg_p"] = 3 - cfg["loss"]["recon_fg_p"]  # 1 <-> 2
        (d / ".hydra" / "config.yaml").write_text(yaml.safe_dump(cfg))
    runs = {r.path.name: r for r in find_runs([tmp_path])}
    assert setting(runs["baseline"]) == "model=baseline"
    assert "loss.weights.recon_N=" in setting(runs["explicit"]) and "loss.recon_fg_p=" in setting(runs["explicit"])
    # compared across models, the baseline joins the explicit runs it trains the same as, and leaves its own group
    groups = group_by_setting(list(runs.values()))
    assert list(groups) == [setting(runs["explicit"], drop_model=True)]
    assert sorted(r.model for r in groups[setting(runs["explicit"], drop_model=True)]) == ["baseline", "explicit"]
    alone = group_by_setting([runs["baseline"]])
    assert list(alone) == ["(defaults)"]


def test_an_early_weight_is_part_of_a_setting_only_where_it_reaches_training(tmp_path):
    """``loss.early_weights`` is an empty map in conf/, so a run's early weight reads ``+key=value`` (what one types
    to train it again); the explicit model has no E_UV, so its early UV weight is no part of its setting, and neither
    is an early weight given no early steps or one equal to the term's own weight."""
    from disent.runs import composed_config, setting

    weight = composed_config(("model=implicit",))["loss"]["weights"]["UV"]
    early = (f"+loss.early_weights.UV={weight + 40:g}", "loss.early_steps=300")
    make_run(tmp_path, "implicit", "implicit", extra=early)
    make_run(tmp_path, "explicit", "explicit", extra=early)
    make_run(tmp_path, "no_steps", "implicit", extra=early[:1])
    make_run(tmp_path, "same", "implicit", extra=(f"+loss.early_weights.UV={weight:g}", "loss.early_steps=300"))
    runs = {r.path.name: r for r in find_runs([tmp_path])}
    assert setting(runs["implicit"]) == f"{early[0]} loss.early_steps=300 model=implicit"
    assert setting(runs["explicit"]) == "model=explicit"
    assert setting(runs["no_steps"]) == setting(runs["same"]) == "model=implicit"


def test_a_weight_typed_as_an_int_is_the_setting_of_the_same_float_in_a_config(tmp_path):
    """``loss.weights.UV=1`` on the command line (an int) and ``UV: 1.0`` in a config (a float) train the same run:
    one setting, not two."""
    from disent.runs import setting

    weight = composed_config(("model=implicit",))["loss"]["weights"]["UV"]
    make_run(tmp_path, "typed", "implicit", extra=(f"loss.weights.UV={int(weight) + 1}",))
    d = make_run(tmp_path, "yaml", "implicit")
    cfg = yaml.safe_load((d / ".hydra" / "config.yaml").read_text())
    cfg["loss"]["weights"]["UV"] = float(int(weight) + 1)
    (d / ".hydra" / "config.yaml").write_text(yaml.safe_dump(cfg))
    runs = {r.path.name: r for r in find_runs([tmp_path])}
    assert runs["typed"].cfg["loss"]["weights"]["UV"] == int(weight) + 1
    assert setting(runs["typed"]) == setting(runs["yaml"]) == f"loss.weights.UV={float(int(weight) + 1)} model=implicit"


def test_a_curve_ending_above_the_panel_is_marked_at_its_edge_with_its_value():
    """A broken run whose final error lies above a learning-curve panel's y limit gets an arrow at the top edge
    labelled with its value; a run inside the panel gets none; ends at nearly one x share a label."""
    from disent.report.training import mark_off_chart

    plt = pyplot()
    fig, ax = plt.subplots()
    ax.plot([0, 10], [20, 64.07])
    ax.set_ylim(0, 51.2)
    ax.set_xlim(0, 10)
    assert mark_off_chart(ax, [(10, 64.07, "C0"), (10, 12.0, "C1"), (2, 80.89, "C2"), (9.8, 82.2, "C3")]) == [
        80.89,
        82.2,
        64.07,
    ]
    labels = {t.get_text(): t.get_color() for t in ax.texts}
    assert sorted(labels) == ["64.1, 82.2", "80.9"]
    assert labels["80.9"] == "C2" and labels["64.1, 82.2"] == "0.2"  # a shared label of two lines: neutral
    assert all(t.xy[1] == 51.2 for t in ax.texts)  # the arrow points at the edge, not at the clipped value
    assert {t.get_text(): t.get_ha() for t in ax.texts} == {"64.1, 82.2": "right", "80.9": "center"}  # runs inwards
    plt.close(fig)


def test_target_reading_says_whether_the_target_lies_outside_the_interval():
    """A row's test accuracy against the order target: reached or not, and beyond the sampling spread only where
    the target lies outside the accuracy's 95 % interval (0.80 over 300 scenes: 0.75-0.84; over 60: 0.68-0.88)."""
    from disent.report.lighting import ORDER_TARGET, target_reading, wilson_interval

    assert wilson_interval(0.80, 300)[1] < ORDER_TARGET < wilson_interval(0.80, 60)[1]
    assert target_reading(0.80, 300) == "**not reached**, the target above its interval"
    assert target_reading(0.80, 60).startswith("**not reached**, but the target lies inside its interval")
    assert target_reading(0.95, 300) == "**reached**, the target below its interval"
    assert target_reading(0.88, 60).startswith("**reached**, but the target lies inside")


def test_wilson_interval_matches_the_closed_form():
    """Wilson's 95 % score interval: 50 of 100 gives 0.404-0.596 (the textbook value); it stays inside [0, 1] at
    0 and n successes, where the normal approximation would not."""
    from disent.report.lighting import wilson_interval

    lo, hi = wilson_interval(0.5, 100)
    assert lo == pytest.approx(0.4038, abs=1e-4) and hi == pytest.approx(0.5962, abs=1e-4)
    assert wilson_interval(0.0, 20)[0] == pytest.approx(0.0, abs=1e-12) and 0 < wilson_interval(0.0, 20)[1] < 0.2
    assert wilson_interval(1.0, 20)[1] == pytest.approx(1.0, abs=1e-12)


def test_paired_order_outcomes_count_the_discordant_scenes_and_mcnemar_is_exact():
    """Two rows compared on the scenes both read (face and true order): the scenes each alone gets right, and the
    exact McNemar p-value (0 against 5 discordant scenes: 2 / 2^5; an even split: 1); a row without its scenes'
    outcomes is not compared."""
    from disent.report.lighting import mcnemar_p, paired_outcomes, paired_reading

    def row(index, true, chosen):
        return {"scenes": {"index": index, "true_order": true, "evidence": chosen}}

    order = {  # scene (3, 2) is read by a alone; of the four shared, a alone is right on 2, b alone on 1, both on 1
        "val/a": row([0, 1, 2, 0, 3], [0, 0, 1, 2, 2], [0, 0, 1, 1, 2]),
        "val/b": row([0, 1, 2, 0], [0, 0, 1, 2], [1, 2, 1, 2]),
        "val/c": {"evidence": {"accuracy": 0.5}},
    }
    assert paired_outcomes(order, "val/a", "val/b") == (4, 2, 1)
    assert paired_outcomes(order, "val/b", "val/a") == (4, 1, 2)
    assert paired_outcomes(order, "val/a", "val/c") is None and paired_reading(order, "val", "a", "c", "c") == ""
    assert mcnemar_p(0, 5) == pytest.approx(2 / 2**5) and mcnemar_p(5, 0) == pytest.approx(2 / 2**5)
    assert mcnemar_p(4, 4) == pytest.approx(1.0) and mcnemar_p(0, 0) == 1.0
    assert "2 right only under it and 1 only under b" in paired_reading(order, "val", "a", "b", "b")


def test_failure_region_lines_flag_the_parts_taking_twice_their_share():
    """The table of where the order choice's misfit lies: one row per split and kind of error, each part's share of
    the reduction beside its share of the pixels, and the parts at twice their share named (none where none is)."""
    from disent.report.lighting import failure_region_lines

    def kind(reduction, pixels):
        parts = ("silhouette", "eyes and brows", "rest")
        return {"scenes": 3, "reduction_share": dict(zip(parts, reduction)), "pixel_share": dict(zip(parts, pixels))}

    regions = {
        "val": {"row": "texture/x", "split": "val", "kinds": {"1->2": kind((0.2, 0.5, 0.3), (0.2, 0.1, 0.7))}},
        "test": {"row": "texture/x", "split": "test", "kinds": {"0->1": kind((0.3, 0.1, 0.6), (0.3, 0.1, 0.6))}},
    }
    text = "\n".join(failure_region_lines(regions))
    assert "| val | 1 -> 2 | 3 | 0.20 (0.20) | 0.50 (0.10) | 0.30 (0.70) |" in text
    assert "| test | 0 -> 1 | 3 |" in text
    assert "twice their share of the pixels: val 1 -> 2: eyes and brows." in text
    assert failure_region_lines({}) == [] and failure_region_lines({"val": {}}) == []
    regions["val"]["kinds"]["1->2"] = kind((0.2, 0.1, 0.7), (0.2, 0.1, 0.7))
    assert "twice their share of the pixels: none." in "\n".join(failure_region_lines(regions))


def test_background_diagnostic_sets_edits_through_the_background_against_the_face_codes():
    """``edit measure --background`` results: per attribute and method, the best success of the sets holding the
    background code beside the best of the face codes alone; none measured, no lines."""
    from disent.report.claims import background_lines

    claims = [
        {"attribute": "senior", "method": "dmt", "manifolds": "paper:Ae+Ne", "best_success": 0.0},
        {"attribute": "senior", "method": "dmt", "manifolds": "Ae", "best_success": 0.06},
        {"attribute": "senior", "method": "dmt", "manifolds": "bg", "best_success": 1.0},
        {"attribute": "senior", "method": "dmt", "manifolds": "all+bg", "best_success": 0.94},
    ]
    lines = background_lines([("explicit", "shipped", {"claims": claims})])
    assert "- explicit (`shipped`): senior by dmt: 1.00 with it, 0.06 with the face codes alone." in lines
    assert background_lines([]) == []


def test_wrapped_titles_break_only_between_name_parts_and_keep_every_character():
    """A figure title's lines stay within the width wherever a break is allowed, never split a name between its
    ``_``/``-``/``.``/space-separated parts, and lose nothing but the spaces at the breaks."""
    from disent.images import wrapped

    text = "+experiment=long loss.bws_c=0.3 (explicit_long_gpu_s12-explicit_s0)"
    lines = wrapped(text, 22).split("\n")
    assert len(lines) > 1 and all(len(line) <= 22 for line in lines), lines
    assert "".join(lines).replace(" ", "") == text.replace(" ", "")
    at = 0
    for line in lines[:-1]:  # each break follows a separator of the original text
        at = text.index(line, at) + len(line)
        at += text[at] == " "
        assert text[at - 1] in " _-.", (line, text[at - 1])
    assert wrapped("supercalifragilistic", 5) == "supercalifragilistic"  # no break inside a part
    assert wrapped("a b", 22) == "a b"


def test_unoverlap_moves_point_labels_apart_and_keeps_the_highest_in_place():
    """Six labels of nearly one point: afterwards no two texts overlap, the highest has not moved, and each still
    points at its own point."""
    from matplotlib.text import Text

    plt = pyplot()
    fig, ax = plt.subplots()
    points = [(0.5, 0.5 + 0.001 * i) for i in range(6)]
    labels = [
        ax.annotate(f"label {i}", p, textcoords="offset points", xytext=(4, 3), arrowprops={"arrowstyle": "-"})
        for i, p in enumerate(points)
    ]
    fig.tight_layout()
    renderer = fig.canvas.get_renderer()
    boxes = lambda: [Text.get_window_extent(t, renderer) for t in labels]  # noqa: E731
    assert any(a.overlaps(b) for i, a in enumerate(boxes()) for b in boxes()[i + 1 :])
    document.unoverlap(ax, labels)
    after = boxes()
    assert not any(a.overlaps(b) for i, a in enumerate(after) for b in after[i + 1 :])
    assert labels[-1].xyann == (4, 3) and all(t.xyann[1] < 3 for t in labels[:-1])
    assert [t.xy for t in labels] == points
    plt.close(fig)


def test_conf_at_a_revision_is_that_revisions_conf():
    """``conf_at``: the ``conf/`` folder of a git revision (where the checkout has its history), None for a revision
    git does not know."""
    from disent.runs import CONF_DIR, conf_at

    head = conf_at("HEAD")
    if head is None:
        pytest.skip("no git history here")
    committed = subprocess.run(
        ["git", "-C", str(CONF_DIR.parent), "show", "HEAD:conf/config.yaml"], capture_output=True, text=True
    ).stdout
    assert (Path(head) / "config.yaml").read_text() == committed
    assert conf_at("0000000000000000000000000000000000000000") is None
