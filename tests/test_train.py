"""Training under Hydra: run folders, exact resume, NaN stops, config errors, a multirun of the three models."""
import json
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from hydra.errors import ConfigCompositionException, MissingConfigException

from disent import losses as L
from disent.models import load_run
from disent.runs import load_checkpoint
from disent.train import NonFiniteLoss, run

ROOT = Path(__file__).resolve().parents[1]
TINY = ["+experiment=smoke", "data.train_size=8", "data.test_size=4", "train.eval_size=4",
        "train.batch_size=4", "train.threads=1"]


def cfg_of(*overrides):
    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        return compose(config_name="config", overrides=list(overrides))


def records(run_dir):
    return [json.loads(l) for l in (Path(run_dir) / "metrics.jsonl").read_text().splitlines()]


def test_misspelt_group_or_key_gets_hydras_error_with_the_choices():
    with pytest.raises(MissingConfigException) as e:
        cfg_of("model=explict")
    assert "Available options" in str(e.value) and "explicit" in str(e.value) and "implicit" in str(e.value)
    with pytest.raises(MissingConfigException, match="no_bws"):
        cfg_of("+ablation=no_bwss")
    with pytest.raises(ConfigCompositionException, match="lrr"):
        cfg_of("train.lrr=1")


def test_ablations_compose():
    cfg = cfg_of("+ablation=[no_bws,no_adv,no_matting]")
    w = cfg.loss.weights
    assert w.BWS == 0 and w.adv == 0 and w.M == 0 and not cfg.model.matting
    assert w.recon > 0 and w.recon_N > 0 and w.smooth_A > 0


def test_resume_equals_an_uninterrupted_run(tmp_path):
    """2 epochs of 2 steps; one run stops mid-epoch 1 and resumes: weights, optimisers and logs agree bitwise."""
    common = [*TINY, "train.epochs=2", "train.max_steps=null", "train.checkpoint_every=100", "train.warmup_steps=2"]
    run(cfg_of(*common), tmp_path / "full")
    run(cfg_of(*common, "train.max_steps=3"), tmp_path / "cut")
    run(cfg_of(*common), tmp_path / "cut")  # same folder: continues from checkpoints/last.pt
    a, b = (load_checkpoint(tmp_path / d / "checkpoints" / "last.pt") for d in ("full", "cut"))
    assert a["step"] == b["step"] == 4
    for part in ("model", "disc"):
        for k in a[part]:
            assert torch.equal(a[part][k], b[part][k]), (part, k)
    assert torch.equal(a["opt_g"]["state"][0]["square_avg"], b["opt_g"]["state"][0]["square_avg"])
    strip = lambda rs: [{k: v for k, v in r.items() if k not in ("wall", "images_per_s", "eval")} for r in rs]
    assert strip(records(tmp_path / "full")) == strip(records(tmp_path / "cut"))
    assert json.loads((tmp_path / "full" / "eval.json").read_text())["recon_mse"] == \
        json.loads((tmp_path / "cut" / "eval.json").read_text())["recon_mse"]


def test_nonfinite_loss_stops_naming_the_term_and_keeps_the_last_good_checkpoint(tmp_path, monkeypatch):
    calls = {"n": 0}
    bws = L.TERM_FUNCTIONS["BWS"]

    def flaky(out, batch, c=0.75):
        calls["n"] += 1
        v = bws(out, batch, c)
        return v * float("nan") if calls["n"] == 4 else v

    monkeypatch.setitem(L.TERM_FUNCTIONS, "BWS", flaky)
    with pytest.raises(NonFiniteLoss, match=r"'BWS' is not finite at step 3.*step 2"):
        run(cfg_of(*TINY, "train.epochs=3", "train.max_steps=null", "train.checkpoint_every=2"), tmp_path)
    ck = load_checkpoint(tmp_path / "checkpoints" / "last.pt")
    assert ck["step"] == 2 and all(torch.isfinite(v).all() for v in ck["model"].values())
    model, cfg = load_run(tmp_path)
    assert cfg.model.name == "explicit" and not model.training


def test_multirun_of_the_three_models(tmp_path):
    """The CI multirun: baseline, explicit and implicit, two steps each on tiny data, through the CLI."""
    cmd = [sys.executable, "-m", "disent", "-m", *TINY, "train.max_steps=2", "model=baseline,explicit,implicit",
           f"hydra.sweep.dir={tmp_path}"]
    res = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-3000:]
    jobs = sorted(p for p in tmp_path.iterdir() if p.is_dir() and (p / ".hydra").exists())
    assert len(jobs) == 3
    names = set()
    for job in jobs:
        cfg = (job / ".hydra" / "config.yaml").read_text()
        names.add(next(l.split()[1] for l in cfg.splitlines() if l.strip().startswith("name:") and "synth" not in l))
        assert (job / "git.txt").read_text().startswith("revision:")
        recs = records(job)
        train = [r for r in recs if "total" in r]
        assert [r["step"] for r in train] == [1, 2]
        assert all({"step", "epoch", "wall", "images_per_s", "recon", "adv", "D", "total"} <= set(r) for r in train)
        ev = json.loads((job / "eval.json").read_text())
        assert ev["recon_mse"] > 0 and "eval" in recs[-1]
        assert (job / "samples" / "final.png").stat().st_size > 0
        assert load_checkpoint(job / "checkpoints" / "last.pt")["step"] == 2
        if "normal_mean" in ev:  # the rendering models: network vs pseudo-GT normals on the same pixels
            assert 0 < ev["normal_mean"] < 180 and 0 < ev["pseudo_normal_mean"] < 180
            assert {"recon_N", "recon_L", "smooth_A", "smooth_S", "BWS", "M"} <= set(train[0])
    assert names == {"baseline", "explicit", "implicit"}
    assert "test metrics" in res.stdout
