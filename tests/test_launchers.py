"""Sweeps through a real launcher: hydra-submitit-launcher's local executor (``hydra/launcher=submitit_local``), the
same code path as SLURM (``hydra/launcher=slurm``), runs a two-job smoke multirun; each job keeps its own folder,
config, metrics and eval.json."""

import json
import subprocess
import sys

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
