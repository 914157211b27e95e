"""Sweeps through a real launcher: hydra-submitit-launcher's local executor (``hydra/launcher=submitit_local``), the
same code path as SLURM (``hydra/launcher=slurm``), runs a two-job smoke multirun; each job keeps its own folder,
config, metrics and eval.json."""

import json
import subprocess
import sys

import pytest
import yaml


def test_a_two_job_sweep_through_submitits_local_executor(tmp_path):
    sweep = tmp_path / "sweep"
    cmd = [
        *(sys.executable, "-m", "disent", "-m", "hydra/launcher=submitit_local", "+experiment=smoke"),
        *("model=baseline,explicit", "train.max_steps=2", "data.test_size=8", "train.eval_size=8"),
        *("train.val_every=0", "train.threads=1", f"hydra.sweep.dir={sweep}", "hydra.launcher.timeout_min=5"),
    ]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "Submitit 'local' sweep" in done.stdout + done.stderr  # the launcher that ran it
    for job, model in (("0", "baseline"), ("1", "explicit")):
        folder = sweep / job
        assert json.loads((folder / "status.json").read_text())["status"] == "ok"
        assert yaml.safe_load((folder / ".hydra" / "config.yaml").read_text())["model"]["name"] == model
        metrics = json.loads((folder / "eval.json").read_text())
        assert metrics["steps"] == 2 and metrics["recon_mse"] > 0
        assert (folder / "checkpoints" / "last.pt").is_file() and (folder / "metrics.jsonl").is_file()
    assert any((sweep / ".submitit").rglob("*_log.out"))  # submitit's own job logs, as on a cluster


TIMING = ("wall", "images_per_s", "seconds", "train_seconds", "minutes")


def untimed(value):
    """A record without its timing fields (what differs between two runs of the same numbers)."""
    if isinstance(value, dict):
        return {k: untimed(v) for k, v in value.items() if k not in TIMING and "per_s" not in k}
    if isinstance(value, list):
        return [untimed(v) for v in value]
    return value


def test_runs_trained_together_in_one_process_equal_each_run_trained_alone(tmp_path):
    """``train.together=true``: a two-seed sweep set up job by job and trained side by side in one process gives each
    run its own folder, config, checkpoint, eval.json and seed, and the numbers that run trains to alone; with
    ``train.stack=true`` the two train as one stacked model, equal to alone to float rounding, and runs that differ
    beyond their seed fall back to side by side; another launcher is refused, before anything trains."""
    tiny = [
        *("+experiment=smoke", "data.train_size=8", "data.test_size=4", "train.eval_size=4", "train.batch_size=4"),
        *(
            "train.threads=1",
            "train.val_every=1",
            "train.val_size=4",
            "train.max_steps=3",
            "train.epochs=2",
            "train.progress=false",
        ),
    ]
    sweep, alone = tmp_path / "together", tmp_path / "alone"
    base = [sys.executable, "-m", "disent", "-m", "seed=0,1", *tiny]
    done = subprocess.run([*base, "train.together=true", f"hydra.sweep.dir={sweep}"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "training 2 run(s) together" in done.stdout
    done = subprocess.run([*base, f"hydra.sweep.dir={alone}"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]
    for job in ("0", "1"):
        a, b = sweep / job, alone / job
        assert json.loads((a / "status.json").read_text())["status"] == "ok" and (a / "checkpoints/last.pt").is_file()
        assert yaml.safe_load((a / ".hydra" / "config.yaml").read_text())["seed"] == int(job)
        ea, eb = (untimed(json.loads((f / "eval.json").read_text())) for f in (a, b))
        assert ea == eb and ea["steps"] == 3
        ma, mb = ([untimed(json.loads(x)) for x in (f / "metrics.jsonl").read_text().splitlines()] for f in (a, b))
        assert ma == mb and sum("val" in r for r in ma) == 3
    ea0, ea1 = (json.loads((sweep / j / "eval.json").read_text()) for j in "01")
    assert ea0["recon_mse"] != ea1["recon_mse"]  # two seeds, two runs: not one run written twice

    # train.stack=true: the same two runs as one stacked model (one vmap of the step), equal to alone to float
    # rounding: after 3 steps the headline test metrics and every step's total loss within 1e-3 relative
    stacked = tmp_path / "stacked"
    done = subprocess.run(
        [*base, "train.together=true", "train.stack=true", f"hydra.sweep.dir={stacked}"], capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert "training 2 run(s) stacked" in done.stdout
    for job in ("0", "1"):
        a, b = stacked / job, alone / job
        assert json.loads((a / "status.json").read_text())["status"] == "ok" and (a / "checkpoints/last.pt").is_file()
        ea, eb = (json.loads((f / "eval.json").read_text()) for f in (a, b))
        for key in ("recon_mse", "normal_mean", "albedo_si_mse", "recon_face_psnr", "sh_error"):
            assert ea[key] == pytest.approx(eb[key], rel=1e-3), key
        assert ea["steps"] == 3
        ma, mb = ([json.loads(x) for x in (f / "metrics.jsonl").read_text().splitlines()] for f in (a, b))
        assert [r["step"] for r in ma] == [r["step"] for r in mb]
        for ra, rb in zip(ma, mb):
            if "total" in rb:
                assert ra["total"] == pytest.approx(rb["total"], rel=1e-3) and ra["D"] == pytest.approx(
                    rb["D"], rel=1e-3
                )
            if "val" in rb:
                assert ra["val"]["normal_mean"] == pytest.approx(rb["val"]["normal_mean"], rel=1e-3)
    other = [*base[:4], "seed=0", "train.lr=1e-4,2e-4", *tiny, "train.together=true", "train.stack=true"]
    done = subprocess.run([*other, f"hydra.sweep.dir={tmp_path / 'mixed'}"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "training side by side instead (their settings differ beyond the seed)" in done.stdout
    assert "training 2 run(s) together" in done.stdout
    refused = subprocess.run(
        [*base, "train.together=true", "hydra/launcher=local", f"hydra.sweep.dir={tmp_path / 'refused'}"],
        capture_output=True,
        text=True,
    )
    assert refused.returncode != 0 and "only Hydra's basic launcher" in refused.stdout + refused.stderr
    assert not list((tmp_path / "refused").rglob("eval.json"))
