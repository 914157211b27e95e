"""No run, result or checkpoint lost to a mistake: unique run folders, one live run per folder, no resume
under other settings, and a damaged checkpoint that costs at most the steps since the previous one."""

import json
import os
import subprocess
import sys
import threading
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest
import torch
from test_train import TINY, cfg_of

from disent.config import ConfigError
from disent.storage import (
    CheckpointError,
    RunFolderBusy,
    RunLock,
    atomic_write,
    load_checkpoint,
    lock_holder,
    previous_checkpoint,
    save_checkpoint,
)
from disent.train import run

ROOT = Path(__file__).resolve().parents[1]
CLI_TINY = [a for a in TINY if a != "train.threads=1"] + ["train.max_steps=2", "train.val_every=0"]


def cli(args, cwd, **kw):
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(ROOT)}
    return subprocess.Popen(
        [sys.executable, "-m", "disent", *args],
        cwd=cwd,
        env=env,
        text=True,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        **kw,
    )


@pytest.fixture
def live_pid():
    """The PID of a live process that is not this one."""
    p = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    yield p.pid
    p.kill()
    p.wait()


def test_two_runs_started_together_get_their_own_folders(tmp_path):
    a = cli([*CLI_TINY, "seed=0"], tmp_path)
    b = cli([*CLI_TINY, "seed=1", "model=baseline"], tmp_path)
    outs = [a.communicate(timeout=300)[0], b.communicate(timeout=300)[0]]
    assert a.returncode == 0 and b.returncode == 0, outs
    folders = sorted(p.parent.parent for p in (tmp_path / "outputs").rglob(".hydra/config.yaml"))
    assert len(folders) == 2
    seen = set()
    for f in folders:
        assert json.loads((f / "status.json").read_text())["status"] == "ok"
        cfg = (f / ".hydra" / "config.yaml").read_text()
        seed = int(next(l.split(":")[1] for l in cfg.splitlines() if l.startswith("seed:")))
        steps = [json.loads(l)["step"] for l in (f / "metrics.jsonl").read_text().splitlines() if '"eval"' not in l]
        assert steps == sorted(steps) and len(steps) == len(set(steps))  # one run's records only
        assert torch.load(f / "checkpoints" / "last.pt", weights_only=False)["cfg"]["seed"] == seed
        seen.add(seed)
    assert seen == {0, 1}


def test_a_folder_held_by_a_live_run_is_refused_before_anything_is_written(tmp_path, live_pid):
    folder = tmp_path / "held"
    folder.mkdir()
    (folder / ".lock").write_text(str(live_pid))
    assert lock_holder(folder) == live_pid
    with pytest.raises(RunFolderBusy, match=str(live_pid)):
        run(cfg_of(*TINY), folder)
    p = cli([*CLI_TINY, f"hydra.run.dir={folder}"], tmp_path)
    out = p.communicate(timeout=120)[0]
    assert p.returncode == 1 and out.strip().splitlines()[-1].startswith("error: the run folder")
    assert sorted(x.name for x in folder.iterdir()) == [".lock"]  # no .hydra/, log, status or checkpoint


def test_a_lock_left_by_a_dead_process_is_taken_over_and_released(tmp_path):
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()  # its PID is free now
    (tmp_path / ".lock").write_text(str(p.pid))
    assert lock_holder(tmp_path) is None
    with RunLock(tmp_path):
        assert (tmp_path / ".lock").read_text() == str(os.getpid())
    assert not (tmp_path / ".lock").exists()
    run(cfg_of(*TINY), tmp_path / "run")
    assert not (tmp_path / "run" / ".lock").exists() and (tmp_path / "run" / "eval.json").exists()


def test_resuming_under_other_settings_is_refused_unless_forced(tmp_path):
    folder = tmp_path / "run"
    run(cfg_of(*TINY, "train.max_steps=1"), folder)
    before = (folder / "checkpoints" / "last.pt").read_bytes()
    with pytest.raises(ConfigError, match=r"model.code_dim: 128 -> 64; seed: 0 -> 1\)"):
        run(cfg_of(*TINY, "train.max_steps=2", "seed=1", "model.code_dim=64"), folder)
    assert (folder / "checkpoints" / "last.pt").read_bytes() == before  # nothing touched
    run(cfg_of(*TINY, "train.max_steps=2", "train.eval_size=2"), folder)  # budget and eval may change
    assert load_checkpoint(folder / "checkpoints" / "last.pt")["step"] == 2
    run(cfg_of(*TINY, "train.epochs=2", "train.max_steps=3", "loss.weights.recon_N=1", "resume_force=true"), folder)
    assert load_checkpoint(folder / "checkpoints" / "last.pt")["step"] == 3


def test_a_loss_weight_the_model_cannot_use_does_not_stop_a_resume(tmp_path):
    folder = tmp_path / "run"
    run(cfg_of(*TINY, "model=baseline", "train.max_steps=1"), folder)
    run(cfg_of(*TINY, "model=baseline", "train.max_steps=2", "loss.weights.recon_N=1", "loss.bws_c=0.5"), folder)
    assert load_checkpoint(folder / "checkpoints" / "last.pt")["step"] == 2
    with pytest.raises(ConfigError, match=r"loss.weights.recon: "):
        run(cfg_of(*TINY, "model=baseline", "train.max_steps=3", "loss.weights.recon=1"), folder)


def test_a_setting_added_later_resumes_runs_from_before_it_only_at_its_old_behaviour():
    from disent.config import ADDED_LATER, config_differences

    new = {"seed": 0, "loss": {"recon_p": 2, "recon_fg_p": 2}}
    before = {"seed": 0, "loss": {"recon_p": 2}}  # a checkpoint written before loss.recon_fg_p existed
    assert ADDED_LATER["loss.recon_fg_p"] == 2 and config_differences(before, new) == []
    assert config_differences(before, {**new, "loss": {"recon_p": 2, "recon_fg_p": 1}}) == ["loss.recon_fg_p: 2 -> 1"]
    gray = {"seed": 0, "loss": {"recon_p": 2, "lhat_gray": False}}  # E_recon-L's gray target, off: as before it
    assert config_differences(before, gray) == []
    paper = {**before, "model": {"decoder_convs": 1}}  # the paper's decoder depth: what every earlier run trained
    assert config_differences(before, paper) == []
    assert config_differences(before, {**before, "model": {"decoder_convs": 2}}) == ["model.decoder_convs: 1 -> 2"]
    assert config_differences(before, {**gray, "loss": {"recon_p": 2, "lhat_gray": True}}) == [
        "loss.lhat_gray: False -> True"
    ]


def test_a_damaged_checkpoint_falls_back_to_the_previous_one(tmp_path, capsys):
    folder = tmp_path / "run"
    run(cfg_of(*TINY, "train.max_steps=2", "train.checkpoint_every=1"), folder)
    last = folder / "checkpoints" / "last.pt"
    assert load_checkpoint(previous_checkpoint(last))["step"] == 1 and load_checkpoint(last)["step"] == 2
    last.write_bytes(last.read_bytes()[:100])  # truncated: a bad copy, a full disk
    with pytest.raises(CheckpointError, match=f"{last}.*cannot be read.*previous checkpoint is"):
        load_checkpoint(last)
    run(cfg_of(*TINY, "train.max_steps=2", "train.checkpoint_every=1"), folder)
    out = capsys.readouterr().out
    assert "set aside as last.pt.damaged" in out and f"resumed from {previous_checkpoint(last)} at step 1" in out
    assert load_checkpoint(last)["step"] == 2 and (folder / "checkpoints" / "last.pt.damaged").exists()


def test_save_checkpoint_keeps_the_one_it_replaces(tmp_path):
    path = tmp_path / "last.pt"
    save_checkpoint(path, {"step": 1})
    assert not previous_checkpoint(path).exists()
    save_checkpoint(path, {"step": 2})
    save_checkpoint(path, {"step": 3})
    assert load_checkpoint(path)["step"] == 3 and load_checkpoint(previous_checkpoint(path))["step"] == 2
    assert sorted(p.name for p in tmp_path.iterdir()) == ["last.pt", "prev.pt"]  # no temp files left
    with pytest.raises(CheckpointError, match="no checkpoint at"):
        load_checkpoint(tmp_path / "missing.pt")


def test_parallel_sweep_jobs_share_one_sweep_folder(tmp_path):
    """The joblib launcher runs jobs in worker processes: the folder name's ${pid:} is the launcher's."""
    p = cli(["-m", "hydra/launcher=local", *CLI_TINY, "model=baseline,explicit"], tmp_path)
    out = p.communicate(timeout=300)[0]
    assert p.returncode == 0, out
    sweeps = list((tmp_path / "multirun").glob("*/*"))
    assert len(sweeps) == 1 and sorted(x.name for x in sweeps[0].iterdir() if x.is_dir()) == ["0", "1"]
    assert all((sweeps[0] / j / "eval.json").is_file() for j in ("0", "1"))


def test_loading_a_damaged_checkpoint_names_the_file(tmp_path):
    from disent.edit.__main__ import load_model
    from disent.models import load_run

    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"PK\x03\x04 not a whole checkpoint")
    with pytest.raises(CheckpointError, match=f"the checkpoint {bad} cannot be read"):
        load_run(bad)
    with pytest.raises(SystemExit, match=f"^error: the checkpoint {bad} cannot be read"):
        load_model(str(bad))


def test_tool_folders_publish_their_results_and_nothing_else(tmp_path, monkeypatch):
    """A tool writes into its own folder (outputs/<tool>/<date>/<time>-<pid>/ by default); publishing copies its
    results into reports/<where the tool's results go>, never weights or bookkeeping, and merges benchmark
    sections instead of replacing the file."""
    import json

    from disent.publish import publish
    from disent.storage import tool_folder

    monkeypatch.chdir(tmp_path)
    edit = tool_folder("edit")
    assert edit.parent.parent == Path("outputs") / "edit" and edit.name.endswith(f"-{os.getpid()}")
    assert (edit / ".tool").read_text() == "edit\n" and (edit / "git.txt").exists() and (edit / "command.txt").exists()
    (edit / "explicit").mkdir()
    (edit / "explicit" / "edit.json").write_text("{}")
    (edit / "measure_net.pt").write_bytes(b"weights")
    (edit / "__main__.log").write_text("a Hydra job's log")
    (edit / ".hydra").mkdir()
    (edit / ".hydra" / "config.yaml").write_text("seed: 0")
    written = publish(edit, tmp_path / "reports")
    assert written == [tmp_path / "reports" / "edit" / "explicit" / "edit.json"]
    assert not (tmp_path / "reports" / "edit" / "measure_net.pt").exists()

    reports = tmp_path / "reports"
    (reports / "bench.json").write_text(json.dumps({"models": {"old": 1}, "data": {"kept": 2}}))
    bench = tool_folder("bench", tmp_path / "b")
    (bench / "bench.json").write_text(json.dumps({"models": {"new": 3}}))
    publish(bench, reports)
    assert json.loads((reports / "bench.json").read_text()) == {"models": {"new": 3}, "data": {"kept": 2}}

    # a run measured again (under another name) replaces its earlier published measurement; other runs stay
    def measured(tool, name, run):
        (tool / name).mkdir()
        (tool / name / "edit.json").write_text(json.dumps({"run": run}))

    first = tool_folder("edit", tmp_path / "e1")
    measured(first, "explicit_seed0_5steps_aaaaaa", str(tmp_path / "runs" / "a"))
    measured(first, "explicit_seed1_5steps_cccccc", str(tmp_path / "runs" / "c"))
    measured(first, "implicit", "implicit")  # a shipped model, by name
    publish(first, reports)
    again = tool_folder("edit", tmp_path / "e2")
    measured(again, "explicit_seed0_5steps_bbbbbb", str(tmp_path / "runs" / "x" / ".." / "a"))
    publish(again, reports)
    names = sorted(p.name for p in (reports / "edit").iterdir())
    assert names == ["explicit", "explicit_seed0_5steps_bbbbbb", "explicit_seed1_5steps_cccccc", "implicit"]

    with pytest.raises(FileNotFoundError, match="not a tool folder"):
        publish(tmp_path / "outputs", reports)
    empty = tool_folder("photos", tmp_path / "empty")
    with pytest.raises(FileNotFoundError, match="holds no results"):
        publish(empty, reports)
    with pytest.raises(ValueError, match="are not published"):
        publish(tool_folder("decompose", tmp_path / "d"), reports)


def test_atomic_write_from_threads_at_once(tmp_path):
    """Threads of one process (the prefetch workers) writing one file at the same moment each get their own temp
    file: every rename succeeds, the file holds one writer's whole content, and no temp file is left."""
    n, path = 4, tmp_path / "cache.npz"
    everyone_open = threading.Barrier(n)

    def write(k):
        def body(f):
            f.write(bytes([k]) * 1000)
            everyone_open.wait(timeout=10)  # every thread holds its temp file open before any renames it

        atomic_write(path, body)

    with ThreadPoolExecutor(n) as pool:
        list(pool.map(write, range(n)))  # re-raises a thread's error
    content = path.read_bytes()
    assert len(content) == 1000 and content in {bytes([k]) * 1000 for k in range(n)}
    assert [p.name for p in tmp_path.iterdir()] == ["cache.npz"]
