"""Training under Hydra: run folders, exact resume, NaN stops, config errors, prefetching in the seeded
order, periodic validation, a multirun of the three models."""

import json
import math
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch
from hydra import compose, initialize_config_dir
from hydra.errors import ConfigCompositionException, MissingConfigException

from disent import config as C
from disent import losses as L
from disent import train as T
from disent.data import step_indices
from disent.eval import evaluate as EV
from disent.lighting import targets as TG
from disent.models import load_run
from disent.optim import warm_start
from disent.runtime import Prefetcher
from disent.storage import load_checkpoint
from disent.train import NonFiniteLoss, run

ROOT = Path(__file__).resolve().parents[1]
TINY = [
    "+experiment=smoke",
    "data.train_size=8",
    "data.test_size=4",
    "train.eval_size=4",
    "train.batch_size=4",
    "train.threads=1",
]


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
    assert not cfg.loss.lhat_white  # no_bws also drops the whitened L-hat target
    assert cfg_of("+ablation=no_adv").loss.lhat_white
    assert w.recon > 0 and w.recon_N > 0 and w.smooth_A > 0


def test_stop_step_replays_a_cut_run_on_the_full_schedule(tmp_path):
    """train.stop_step stops where a time-guarded run stopped, on the schedule of the full run: its log is the
    full run's first steps (lr included), unlike a run of max_steps=2, whose cosine decays faster."""
    common = [*TINY, "train.epochs=2", "train.max_steps=null", "train.log_every=1", "train.warmup_steps=0"]
    run(cfg_of(*common), tmp_path / "full")
    run(cfg_of(*common, "train.stop_step=2"), tmp_path / "stopped")
    run(cfg_of(*common, "train.max_steps=2"), tmp_path / "short")
    keep = lambda rs: [{k: v for k, v in r.items() if k in ("step", "lr", "total")} for r in rs if "lr" in r]
    full, stopped, short = (keep(records(tmp_path / d)) for d in ("full", "stopped", "short"))
    assert len(full) == 4 and stopped == full[:2] and short[1]["lr"] < full[1]["lr"]
    ev = json.loads((tmp_path / "stopped" / "eval.json").read_text())
    assert ev["stopped_by"] == "stop_step" and ev["steps"] == 2
    machine = json.loads((tmp_path / "full" / "machine.json").read_text())  # what the run trained on
    assert machine["device"] == "cpu" and machine["cpus"] >= 1 and machine["torch"] == torch.__version__
    with pytest.raises(C.ConfigError, match="stop_step"):
        C.check_config(cfg_of(*common, "train.stop_step=0"))


def test_warm_start_loads_the_weights_and_refuses_another_model(tmp_path):
    run(cfg_of(*TINY, "model=implicit"), tmp_path / "source")
    cfg = cfg_of(*TINY, "model=implicit", f"init={tmp_path / 'source'}")
    model, fresh = T.build_model(cfg.model), T.build_model(cfg.model)
    warm_start(model, cfg)
    source, _ = load_run(tmp_path / "source")
    assert all(torch.equal(v, source.state_dict()[k]) for k, v in model.state_dict().items())
    assert not all(torch.equal(v, fresh.state_dict()[k]) for k, v in model.state_dict().items())
    shipped = cfg_of(*TINY, "init=explicit")  # a shipped name: half precision, cast back on loading
    model = T.build_model(shipped.model)
    warm_start(model, shipped)
    assert next(model.parameters()).dtype == torch.float32
    with pytest.raises(C.ConfigError, match="model.name 'implicit' there, 'explicit' here"):
        warm_start(T.build_model(cfg_of(*TINY).model), cfg_of(*TINY, f"init={tmp_path / 'source'}"))
    with pytest.raises(C.ConfigError, match="model.norm 'batch' there, 'group' here"):
        warm_start(model, cfg_of(*TINY, "model=implicit", "model.norm=group", f"init={tmp_path / 'source'}"))


def test_resume_equals_an_uninterrupted_run(tmp_path, monkeypatch):
    """2 epochs of 2 steps; one run is killed during step 4 (its last checkpoint: the end of epoch 0) and
    started again in its folder: weights, optimisers and logs agree bitwise with the uninterrupted run."""
    common = [
        *TINY,
        "train.epochs=2",
        "train.max_steps=null",
        "train.checkpoint_every=100",
        "train.warmup_steps=2",
        "train.prefetch=2",
        "train.val_every=1",
        "train.val_size=4",
    ]
    run(cfg_of(*common), tmp_path / "full")
    step, calls = T.train_step, []

    def killed_at_step_4(*args, **kw):
        calls.append(1)
        if len(calls) == 4:
            raise KeyboardInterrupt("killed")
        return step(*args, **kw)

    monkeypatch.setattr(T, "train_step", killed_at_step_4)
    with pytest.raises(KeyboardInterrupt):
        run(cfg_of(*common), tmp_path / "cut")
    monkeypatch.setattr(T, "train_step", step)
    assert load_checkpoint(tmp_path / "cut" / "checkpoints" / "last.pt")["step"] == 2
    run(cfg_of(*common), tmp_path / "cut")  # same folder: continues from checkpoints/last.pt
    a, b = (load_checkpoint(tmp_path / d / "checkpoints" / "last.pt") for d in ("full", "cut"))
    assert a["step"] == b["step"] == 4
    for part in ("model", "disc"):
        for k in a[part]:
            assert torch.equal(a[part][k], b[part][k]), (part, k)
    for opt in ("opt_g", "opt_d"):
        for k, v in a[opt]["state"][0].items():
            assert torch.equal(v, b[opt]["state"][0][k]), (opt, k)
    strip = lambda rs: [
        {
            k: ({a: b for a, b in v.items() if a != "seconds"} if k == "val" else v)
            for k, v in r.items()
            if k not in ("wall", "minutes", "images_per_s", "eval")
        }
        for r in rs
    ]
    assert strip(records(tmp_path / "full")) == strip(records(tmp_path / "cut"))
    assert [r["step"] for r in records(tmp_path / "cut") if "val" in r] == [1, 2, 3, 4]
    full, cut = (scalars(tmp_path / d / "tensorboard") for d in ("full", "cut"))  # the retrained steps purged
    assert [s for s, _ in cut["loss/total"]] == [s for s, _ in full["loss/total"]]
    assert [s for s, _ in cut["val/normal_mean"]] == [1, 2, 3, 4]
    assert (
        json.loads((tmp_path / "full" / "eval.json").read_text())["recon_mse"]
        == json.loads((tmp_path / "cut" / "eval.json").read_text())["recon_mse"]
    )


def test_prefetcher_yields_make_batch_in_step_order_and_keeps_the_callers_threads():
    seen = []

    def make_batch(step):
        seen.append(torch.get_num_threads())
        time.sleep(0.02 if step % 2 else 0)  # with several workers, later steps finish first
        return {"image": torch.full((1,), float(step))}

    threads = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        for depth, workers in ((0, 1), (1, 1), (3, 3)):
            p = Prefetcher(make_batch, range(5, 12), depth, workers)
            assert [p.get(s)["image"].item() for s in range(5, 12)] == list(range(5, 12))
            p.close()
            assert torch.get_num_threads() == 2  # the worker renders on one thread, the caller keeps two
        assert seen == [2] * 7 + [1] * 14  # depth 0 renders in the caller
        p = Prefetcher(make_batch, range(3), 2)
        with pytest.raises(RuntimeError, match="out of order: asked for step 1, has step 0"):
            p.get(1)
        p.close()
    finally:
        torch.set_num_threads(threads)


def test_prefetcher_reraises_the_workers_error_and_close_stops_it():
    def make_batch(step):
        if step == 2:
            raise ValueError("bad image 2")
        return {"step": step}

    p = Prefetcher(make_batch, range(10), 2)
    assert p.get(0)["step"] == 0 and p.get(1)["step"] == 1
    with pytest.raises(ValueError, match="bad image 2"):
        p.get(2)
    p.close()
    calls = []
    p = Prefetcher(lambda s: calls.append(s) or {"step": s}, range(10**6), 2, workers=3)  # endless steps
    assert p.get(0)["step"] == 0
    p.close()  # stops the workers: nothing more is rendered
    made = len(calls)
    time.sleep(0.2)
    assert len(calls) == made <= 4


@pytest.mark.parametrize("prefetch", [0, 2])
def test_training_sees_the_seeded_data_order_with_and_without_prefetch(tmp_path, monkeypatch, prefetch):
    """Every step trains on its slice of the epoch's seeded permutation, whatever train.prefetch is
    (resume replays these exact steps)."""
    seen = []
    get_batch = T.get_batch

    def recording(dataset, indices, *a):
        if dataset.split == "train" and len(indices) == 4:
            seen.append(torch.as_tensor(indices).tolist())
        return get_batch(dataset, indices, *a)

    monkeypatch.setattr(T, "get_batch", recording)
    run(cfg_of(*TINY, "train.epochs=2", "train.max_steps=null", f"train.prefetch={prefetch}", "seed=3"), tmp_path)
    expected = [step_indices(3, s, 2, 4, 8).tolist() for s in range(4)]
    assert seen == expected
    assert expected[0] != expected[2] and sorted(expected[0] + expected[1]) == list(range(8))  # a new order each epoch


def test_fitted_lhat_targets_are_fitted_once_per_training_image(tmp_path, monkeypatch):
    """loss.recon_L_target=sh_texture (or sh_pseudo_eroded, sh_network): each step's batch carries its images'
    texture-model L-hat (or L-hat on M-hat eroded, a network's light), fitted the first time an image comes (two
    epochs of 8 images: 8 fits, none in the second epoch), in the batch's order; the evaluation draws it once more
    for the test faces it scores the target on (``target_light_*``)."""
    import disent.lighting.targets as E  # the fits the trainer draws its targets from

    fitted = []

    def fake(batch):  # a light that names its image: its mean pixel value in the DC coefficient
        fitted.append(len(batch["image"]))
        return torch.cat([batch["image"].mean((2, 3))[..., None], torch.zeros(len(batch["image"]), 3, 8)], 2)

    monkeypatch.setattr(E, "texture_lhat", fake)
    cache = {}
    b = {
        k: torch.rand(4, c, 8, 8) for k, c in (("image", 3), ("normal_pseudo", 3), ("mask_pseudo", 1), ("uv_pseudo", 2))
    }
    first = TG.with_fitted_lhat(b, torch.tensor([5, 1, 7, 2]), cache, "sh_texture", fake)
    torch.testing.assert_close(first["sh_texture"][:, :, 0], b["image"].mean((2, 3)))
    again = TG.with_fitted_lhat({**b, "image": b["image"].flip(0)}, [2, 7, 1, 5], cache, "sh_texture", fake)  # cached
    assert fitted == [4] and torch.equal(again["sh_texture"], first["sh_texture"].flip(0))
    TG.with_fitted_lhat(b, [5, 3, 0, 1], cache, "sh_texture", fake)
    assert fitted == [4, 2] and sorted(cache) == [0, 1, 2, 3, 5, 7]
    fitted.clear()
    rescaled, real = [], L.rescaled  # loss.recon_L_scale=sh_pseudo: each step's target is taken to L-hat's scale
    monkeypatch.setattr(L, "rescaled", lambda light, reference, *a: rescaled.append(1) or real(light, reference, *a))
    run(cfg_of(*TINY, "train.epochs=2", "train.max_steps=null", "loss.recon_L_target=sh_texture"), tmp_path / "own")
    assert fitted == [4, 4, 4] and all(r["recon_L"] > 0 for r in records(tmp_path / "own") if "recon_L" in r)
    scored = json.loads((tmp_path / "own" / "eval.json").read_text())
    assert scored["target_light_shading_si_mse"] > 0 and "target_light_pattern_corr" in scored
    assert not rescaled
    overrides = ("train.max_steps=2", "loss.recon_L_target=sh_texture", "loss.recon_L_scale=sh_pseudo")
    run(cfg_of(*TINY, *overrides), tmp_path / "lhat_scale")
    assert len(rescaled) == 3  # two steps and the evaluation
    eroded = []  # loss.recon_L_target=sh_pseudo_eroded: L-hat on M-hat eroded, fitted once per image as well
    monkeypatch.setattr(E, "eroded_lhat", lambda batch: eroded.append(len(batch["image"])) or fake(batch))
    run(cfg_of(*TINY, "train.epochs=2", "train.max_steps=null", "loss.recon_L_target=sh_pseudo_eroded"), tmp_path / "e")
    assert eroded == [4, 4, 4] and all(r["recon_L"] > 0 for r in records(tmp_path / "e") if "recon_L" in r)
    drawn = []  # loss.recon_L_target=sh_network: the named network's light of each image, drawn once per image
    monkeypatch.setattr(E, "network_lhat", lambda batch, network: drawn.append(network) or fake(batch))
    overrides = ("train.epochs=2", "train.max_steps=null", "loss.recon_L_target=sh_network")
    run(cfg_of(*TINY, *overrides, "loss.recon_L_network=implicit"), tmp_path / "n")
    assert drawn == ["implicit"] * 3 and all(r["recon_L"] > 0 for r in records(tmp_path / "n") if "recon_L" in r)
    drawn.clear()  # sh_network_texture: the same, through its own fit, at loss.recon_L_network_share
    monkeypatch.setattr(E, "network_texture_lhat", lambda b, network, share: drawn.append((network, share)) or fake(b))
    run(cfg_of(*TINY, "train.max_steps=2", "loss.recon_L_target=sh_network_texture"), tmp_path / "nt")
    assert drawn == [("explicit", 0.6)] * 3
    drawn.clear()
    overrides = ("train.max_steps=2", "loss.recon_L_target=sh_network_texture", "loss.recon_L_network_share=0.25")
    run(cfg_of(*TINY, *overrides), tmp_path / "nt25")
    assert drawn == [("explicit", 0.25)] * 3


def test_the_evaluation_scores_the_target_a_setting_teaches():
    """target_light_of: nothing for the paper's L-hat (scored as pseudo_*); an oracle dose is L-hat moved toward the
    truth, as E_recon-L sees it before BWS's scale; a fitted target is drawn through its fit."""
    from disent.data import SynthFaces, get_batch

    assert TG.target_light_of(cfg_of().loss) is None
    b = get_batch(SynthFaces("test", size=3), range(3))
    dose = TG.target_light_of(cfg_of("loss.recon_L_oracle_mix=0.5").loss)(b)
    torch.testing.assert_close(dose, L.oracle_mixed(b["sh_pseudo"], b["sh"], b["normal_pseudo"], b["mask_pseudo"], 0.5))
    assert not torch.allclose(dose, b["sh_pseudo"])
    texture = TG.target_light_of(cfg_of("loss.recon_L_target=sh_texture").loss)(b)
    torch.testing.assert_close(texture, __import__("disent.lighting.targets").lighting.targets.texture_lhat(b))


def test_network_target_is_the_named_networks_own_light():
    """loss.recon_L_target=sh_network: the light the shipped model draws from each image, as the lighting section's
    network row scores it; a network that cannot be loaded stops the run at the start, naming the key."""
    from disent.data import SynthFaces, get_batch
    from disent.lighting.targets import network_lhat
    from disent.lighting.texture import trained_network

    b = get_batch(SynthFaces("test", size=2), range(2))
    with torch.no_grad():
        own = trained_network("explicit")(b["image"].clamp(0, 1))["sh"]
    torch.testing.assert_close(network_lhat(b, "explicit"), own)
    assert TG.target_fit({"recon_L_target": "sh_pseudo"}) is None and TG.target_fit({}) is None
    for target in C.NETWORK_TARGETS:
        with pytest.raises(C.ConfigError, match="loss.recon_L_network='nowhere/run'"):
            C.check_config(cfg_of(*TINY, f"loss.recon_L_target={target}", "loss.recon_L_network=nowhere/run"))


def test_network_texture_target_averages_the_networks_light_with_its_texture_refit():
    """loss.recon_L_target=sh_network_texture: at share 0 the network's own light, at share 1 the texture model's
    L-hat through the network's normals and uv (the implicit model draws one) on M-hat eroded inside its matte, and
    between them the average; the explicit model, without uv, reads the pseudo uv."""
    from disent.data import SynthFaces, get_batch
    from disent.lighting.targets import EDGE, eroded, network_texture_lhat
    from disent.lighting.texture import texture_light, trained_network

    b = get_batch(SynthFaces("test", size=2), range(2))
    for name, uv_key in (("implicit", "uv"), ("explicit", None)):
        with torch.no_grad():
            out = trained_network(name)(b["image"].clamp(0, 1))
        mask = eroded(b["mask_pseudo"], EDGE) * (out["matte"] > 0.5)
        refit = texture_light(b["image"], out["normal"], mask, out[uv_key] if uv_key else b["uv_pseudo"]).float()
        torch.testing.assert_close(network_texture_lhat(b, name, share=0), out["sh"])
        torch.testing.assert_close(network_texture_lhat(b, name, share=1), refit)
        torch.testing.assert_close(network_texture_lhat(b, name, share=0.6), 0.6 * refit + 0.4 * out["sh"])
        assert not torch.allclose(refit, out["sh"], atol=1e-2)  # the two differ: the share matters


def test_the_refit_share_has_one_default():
    """loss.recon_L_network_share's default (conf/loss/default.yaml), the lighting tool's (NETWORK_TEXTURE_SHARE) and
    the share of runs from before the key (ADDED_LATER) are one number."""
    from disent.lighting.targets import NETWORK_TEXTURE_SHARE

    assert cfg_of().loss.recon_L_network_share == NETWORK_TEXTURE_SHARE == C.ADDED_LATER["loss.recon_L_network_share"]


def scalars(folder) -> dict:
    """``{tag: [(step, value)]}`` of the TensorBoard event files in ``folder``."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    out = {}
    for events in sorted({p.parent for p in folder.rglob("events.out.tfevents.*")}):
        acc = EventAccumulator(str(events))
        acc.Reload()
        for tag in acc.Tags()["scalars"]:
            out.setdefault(tag, []).extend((e.step, e.value) for e in acc.Scalars(tag))
    return out


def test_tensorboard_shows_the_losses_and_the_validation_beside_its_trivial_baselines(tmp_path):
    """A run's event files hold what metrics.jsonl holds: each loss term at its logged steps, each validation metric
    with the dataset-mean and pseudo-GT lines beside it, and the test metrics at the end."""
    run(cfg_of(*TINY, "train.epochs=3", "train.max_steps=null", "train.val_every=2", "train.val_size=4"), tmp_path)
    got, logged = scalars(tmp_path / "tensorboard"), records(tmp_path)
    losses = [r for r in logged if "total" in r]
    assert [s for s, _ in got["loss/total"]] == [r["step"] for r in losses]
    assert [v for _, v in got["loss/total"]] == pytest.approx([r["total"] for r in losses], rel=1e-6)
    vals = [r for r in logged if "val" in r]
    assert [v for _, v in got["val/normal_mean"]] == pytest.approx([r["val"]["normal_mean"] for r in vals], rel=1e-6)
    assert [v for _, v in got["trivial/normal_mean"]] == pytest.approx(
        [r["val"]["trivial_normal_mean"] for r in vals], rel=1e-6
    )
    assert "pseudo/normal_mean" in got and "val/trivial_normal_mean" not in got and "val/n" not in got
    final = json.loads((tmp_path / "eval.json").read_text())
    assert got["eval/recon_mse"][-1][1] == pytest.approx(final["recon_mse"], rel=1e-6)
    run(cfg_of(*TINY, "train.tensorboard=false"), tmp_path / "off")
    assert not (tmp_path / "off" / "tensorboard").exists()


def test_validation_records_normal_errors_and_psnr(tmp_path):
    run(cfg_of(*TINY, "train.epochs=3", "train.max_steps=null", "train.val_every=2", "train.val_size=4"), tmp_path)
    vals = [r for r in records(tmp_path) if "val" in r]
    assert [r["step"] for r in vals] == [2, 4, 6]
    for r in vals:
        v = r["val"]
        assert r["minutes"] == pytest.approx(r["wall"] / 60) and r["wall"] > 0
        assert 0 < v["normal_mean"] < 180 and 0 < v["pseudo_normal_mean"] < 180 and v["recon_psnr"] > 0
        assert v["n"] == 4 and v["seconds"] > 0
    assert vals[0]["val"]["pseudo_normal_mean"] == vals[-1]["val"]["pseudo_normal_mean"]  # one fixed val subset
    assert vals[0]["val"]["normal_mean"] != vals[-1]["val"]["normal_mean"]  # the network moved


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
    assert cfg.model.name == "explicit" and not model.training and not model.shipped and model.trained_steps == 2


def test_multirun_of_the_three_models(tmp_path):
    """The CI multirun: baseline, explicit and implicit, two steps each on tiny data, through the CLI."""
    cmd = [
        sys.executable,
        "-m",
        "disent",
        "-m",
        *TINY,
        "train.max_steps=2",
        "model=baseline,explicit,implicit",
        f"hydra.sweep.dir={tmp_path}",
    ]
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


def test_learning_rate_schedules():
    """Linear warm-up, then the release's per-epoch decay or a half cosine that reaches 0 at the last step."""
    from omegaconf import OmegaConf

    from disent.optim import learning_rate

    t = OmegaConf.create({"lr": 1e-3, "warmup_steps": 10, "lr_decay": 0.9, "schedule": "epoch_decay"})
    assert learning_rate(t, 0, 100, 1000) == pytest.approx(1e-4)  # (0 + 1) / 10 of lr
    assert learning_rate(t, 250, 100, 1000) == pytest.approx(1e-3 * 0.9**2)
    t.schedule = "cosine"
    assert learning_rate(t, 500, 100, 1000) == pytest.approx(0.5e-3)
    assert learning_rate(t, 999, 100, 1000) == pytest.approx(1e-3 * 0.5 * (1 + math.cos(math.pi * 0.999)))
    lrs = [learning_rate(t, s, 100, 1000) for s in range(10, 1000)]
    assert all(a >= b for a, b in zip(lrs, lrs[1:]))  # monotone after the warm-up
    t.schedule = "linear"
    with pytest.raises(ValueError, match="train.schedule='linear'; choose from epoch_decay, cosine"):
        learning_rate(t, 0, 100, 1000)


@pytest.mark.parametrize(
    "override,message",
    [
        ("train.batch_size=-3", "train.batch_size=-3: must be a whole number >= 1"),
        ("train.batch_size=abc", "train.batch_size='abc': must be a whole number"),
        ("train.batch_size=0", "train.batch_size=0: must be"),
        ("train.batch_size=9", r"train.batch_size=9 exceeds the 8 training images \(data.train_size\)"),
        ("train.epochs=0", "train.epochs=0"),
        ("train.max_steps=-1", "train.max_steps=-1: must be a whole number >= 1 or null"),
        ("train.lr=0", "train.lr=0: must be a positive number"),
        ("train.optimizer=sgd", "train.optimizer='sgd'; choose from rmsprop, adam"),
        ("data.train_size=0", "data.train_size=0"),
        ("loss.recon_p=3", r"loss.recon_p=3; choose from 1 \(L1, the release\), 2"),
        ("loss.recon_fg_p=0", r"loss.recon_fg_p=0; choose from 1 \(L1\), 2"),
        ("loss.matte_p=3", r"loss.matte_p=3; choose from 1 \(L1, the release\), 2"),
        ("loss.recon_L_target=lhat", "loss.recon_L_target='lhat'; choose from sh_pseudo, sh_pseudo_eroded, sh_texture"),
        ("loss.recon_L_scale=sh", "loss.recon_L_scale='sh'; choose from target, sh_pseudo"),
        ("loss.recon_L_oracle_mix=1.5", r"loss.recon_L_oracle_mix=1.5: must be a number in \[0, 1\]"),
        ("loss.recon_L_network_share=-0.1", r"loss.recon_L_network_share=-0.1: must be a number in \[0, 1\]"),
        ("loss.early_steps=-5", "loss.early_steps=-5: must be a whole number >= 0"),
        ("+loss.early_weights.UVV=10", "loss.early_weights.UVV: no such term; terms are recon, "),
        ("+loss.early_weights.UV=-1", r"loss.early_weights.UV=-1: must be a finite number >= 0"),
        ("device=tpu", "device='tpu'; choose from cpu, cuda, cuda:N"),
        ("device=cpu:1", "device='cpu:1'; choose from"),
    ],
)
def test_bad_settings_stop_before_anything_runs(tmp_path, override, message):
    """A setting that cannot run is a ConfigError naming the key and what it accepts, raised before a
    checkpoint or a metric is written (train.batch_size=-3 used to train 0 steps and report success)."""
    from disent.config import ConfigError

    with pytest.raises(ConfigError, match=message):
        run(cfg_of(*TINY, override), tmp_path / "run")
    assert not (tmp_path / "run" / "checkpoints").exists() and not (tmp_path / "run" / "metrics.jsonl").exists()


@pytest.mark.parametrize(
    "overrides,named",
    [
        (("loss.recon_L_oracle_mix=0.5",), "loss.recon_L_oracle_mix=0.5"),
        (("loss.recon_L_target=sh",), "loss.recon_L_target=sh"),
        (("loss=ceiling",), "loss.weights.A_true, loss.weights.N_true, loss.weights.L_true"),
    ],
)
def test_settings_that_read_the_truth_stop_on_photos_before_anything_runs(tmp_path, overrides, named):
    """The true layers (E_recon-L on the true light, the ceiling's terms) exist on SynthFaces alone: on a folder of
    photos each setting that reads them is named in a ConfigError at the start (loss.recon_L_target=sh used to fail
    only at the first step)."""
    from disent.config import ConfigError

    with pytest.raises(ConfigError, match=f"^{named} read\\(s\\) the true layers, which only data=synth has$"):
        run(cfg_of(*TINY, "data=folder", *overrides), tmp_path / "run")
    assert not (tmp_path / "run").exists() or not any((tmp_path / "run").iterdir())


def test_cuda_without_a_gpu_is_one_line(tmp_path):
    if torch.cuda.is_available():
        pytest.skip("this machine has a GPU")
    cmd = [sys.executable, "-m", "disent", *TINY, "device=cuda", f"hydra.run.dir={tmp_path / 'run'}"]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert res.returncode == 1
    assert res.stderr.strip().splitlines() == [
        f"error: device='cuda', but this torch ({torch.__version__}) sees no CUDA GPU; use device=cpu, "
        "or install a CUDA build of torch (README, GPU install)"
    ]


@pytest.mark.parametrize("corrupt_at,saved", [(2, 1), (1, None)])
def test_nonfinite_weights_are_never_saved_as_good(tmp_path, monkeypatch, corrupt_at, saved):
    """An update that overflows the weights while every loss was finite: the next checkpoint refuses to save
    them and the run stops naming a checkpoint that exists (with finite weights), or saying none was written."""
    step_fn, calls = T.train_step, []

    def overflowing(model, *args, **kw):
        out = step_fn(model, *args, **kw)
        calls.append(1)
        if len(calls) == corrupt_at:
            next(model.parameters()).data.fill_(float("inf"))
        return out

    monkeypatch.setattr(T, "train_step", overflowing)
    expect = r"Last good checkpoint: .*last.pt \(step 1\)" if saved else "No checkpoint was written yet"
    with pytest.raises(NonFiniteLoss, match=rf"weights became non-finite by step {corrupt_at} \(0\.encoder.*{expect}"):
        run(cfg_of(*TINY, "train.epochs=3", "train.max_steps=null", "train.checkpoint_every=1"), tmp_path)
    path = tmp_path / "checkpoints" / "last.pt"
    if saved is None:
        assert not path.exists()
    else:
        ck = load_checkpoint(path)
        assert ck["step"] == saved and all(
            torch.isfinite(v).all() for v in ck["model"].values() if v.is_floating_point()
        )


def test_nonfinite_loss_before_any_checkpoint_says_so(tmp_path, monkeypatch):
    monkeypatch.setitem(L.TERM_FUNCTIONS, "BWS", lambda out, batch, c=0.75: torch.tensor(float("nan")))
    with pytest.raises(NonFiniteLoss, match="'BWS' is not finite at step 0 .*No checkpoint was written yet"):
        run(cfg_of(*TINY), tmp_path)


def test_rescore_rewrites_eval_json_and_keeps_the_bookkeeping(tmp_path, capsys):
    from disent.eval.evaluate import main as rescore_main

    folder = tmp_path / "run"
    first = run(cfg_of(*TINY), folder)
    stale = {k: v for k, v in first.items() if k not in ("albedo_si_mse", "trivial_sh_error")}
    stale["train_seconds"], stale["infer_images_per_s"] = 123.0, 45.6  # bookkeeping and speed kept as written
    (folder / "eval.json").write_text(json.dumps(stale))
    rescore_main([str(folder)])
    again = json.loads((folder / "eval.json").read_text())
    assert again["train_seconds"] == 123.0 and again["steps"] == first["steps"] and again["infer_images_per_s"] == 45.6
    for k in ("albedo_si_mse", "trivial_sh_error", "normal_mean", "recon_mse"):
        assert again[k] == pytest.approx(first[k], rel=1e-6, abs=1e-9)  # the same weights, the same numbers
    assert "test metrics" in capsys.readouterr().out


def test_ladder_gpu_script_trains_the_three_models_side_by_side_and_skips_finished_runs(tmp_path):
    """ablations/ladder_gpu.sh, run here on the CPU (DEVICE=cpu) at a tiny budget: one folder per model, each
    trained and evaluated; a second call finds them finished and starts nothing."""
    root = Path(__file__).resolve().parents[1]
    tiny = "train.max_steps=2 train.eval_size=8 data.test_size=8 train.val_size=4 train.val_every=0 "
    tiny += "data.train_size=32 train.batch_size=4 train.checkpoint_every=2 train.threads=1"
    env = {**os.environ, "DEVICE": "cpu", "WORKERS": "2", "PYTHON": sys.executable}
    cmd = ["bash", str(root / "ablations" / "ladder_gpu.sh"), str(tmp_path), "3", *tiny.split()]
    subprocess.run(cmd, cwd=root, env=env, check=True, capture_output=True, timeout=600)
    for model in ("explicit", "implicit", "baseline"):
        run = tmp_path / f"{model}_s3"
        ev = json.loads((run / "eval.json").read_text())
        assert ev["steps"] == 2
        config = (run / ".hydra" / "config.yaml").read_text()
        assert f"name: {model}" in config and "prefetch_workers: 2" in config and "seed: 3" in config
    stamps = {p: p.stat().st_mtime_ns for p in tmp_path.glob("*/eval.json")}
    subprocess.run(cmd, cwd=root, env=env, check=True, capture_output=True, timeout=60)
    assert {p: p.stat().st_mtime_ns for p in tmp_path.glob("*/eval.json")} == stamps


def test_learned_layers_reads_the_matte_higher_is_better(capsys):
    """A layer is learned where it beats its floor: a lower error, but a higher IoU for the matte; print_eval says
    which, on the matte's line too."""
    m = {"matte_iou": 0.9, "trivial_matte_iou": 0.7, "pseudo_matte_iou": 0.86, "normal_mean": 20.0}
    m["trivial_normal_mean"] = 17.0
    assert EV.learned_layers(m) == {"matte_iou": True, "normal_mean": False}
    assert EV.learned_layers({**m, "matte_iou": 0.6}) == {"matte_iou": False, "normal_mean": False}
    EV.print_eval({**m, "n_eval": 4, "recon_mse": 0.01, "recon_psnr": 20.0, "recon_ssim": 0.5}, "run")
    matte = next(line for line in capsys.readouterr().out.splitlines() if "matte" in line)
    assert "0.9" in matte and "0.7" in matte and "pseudo-GT 0.86" in matte and matte.endswith("learned")


def test_print_eval_names_how_the_normals_failed(capsys):
    """The run summary names a frame failure (worse than the mean map, nearer than it once the frame is aligned) and
    prints the error left after the frame map; a learned normal map gets no failure word."""
    m = {"n_eval": 4, "recon_mse": 0.01, "recon_psnr": 20.0, "recon_ssim": 0.5, "trivial_normal_mean": 17.0}
    m |= {"normal_mean": 64.0, "normal_spread": 31.6, "true_normal_spread": 39.1}
    m |= {"normal_aligned_mean": 11.0, "normal_aligned_angle": 58.2, "normal_aligned_det": 1.0}
    EV.print_eval(m, "run")
    out = capsys.readouterr().out
    assert "FRAME" in out and "11.00deg   (a rotation by 58 deg)" in out
    EV.print_eval({**m, "normal_mean": 9.6, "normal_aligned_mean": 9.5}, "run")
    out = capsys.readouterr().out
    assert not any(word in out for word in ("FRAME", "FLAT", "ASTRAY")) and "(a rotation by 58 deg)" in out


def test_the_gpu_suite_script_runs_each_setting_once_and_resumes_after_an_interruption(tmp_path):
    """ablations/suite_gpu.sh on the CPU (DEVICE=cpu) at a tiny budget, two models and one ablation at one seed:
    one folder per run, each trained and evaluated; after one run is cut (its eval.json gone, its checkpoint kept)
    the same command finishes that run alone and leaves the others as they were."""
    root = Path(__file__).resolve().parents[1]
    tiny = "train.max_steps=2 train.eval_size=8 data.test_size=8 train.val_size=4 train.val_every=0 "
    tiny += "data.train_size=32 train.batch_size=4 train.checkpoint_every=2 train.threads=1"
    env = {**os.environ, "DEVICE": "cpu", "WORKERS": "1", "PYTHON": sys.executable, "JOBS": "2", "REPORT": "0"}
    env |= {"SEEDS": "0", "MODELS": "explicit baseline", "ABLATIONS": "no_bws", "EXPERIMENT": "smoke"}
    cmd = ["bash", str(root / "ablations" / "suite_gpu.sh"), str(tmp_path), *tiny.split()]
    subprocess.run(cmd, cwd=root, env=env, check=True, capture_output=True, timeout=600)
    runs = sorted(p.parent.name for p in tmp_path.glob("*/eval.json"))
    assert runs == ["baseline_s0", "explicit_no_bws_s0", "explicit_s0"]
    assert "no_bws" in (tmp_path / "explicit_no_bws_s0" / ".hydra" / "overrides.yaml").read_text()
    (tmp_path / "explicit_s0" / "eval.json").unlink()  # cut after its last checkpoint
    stamps = {p: p.stat().st_mtime_ns for p in tmp_path.glob("*/eval.json")}
    subprocess.run(cmd, cwd=root, env=env, check=True, capture_output=True, timeout=600)
    assert {p: p.stat().st_mtime_ns for p in stamps} == stamps  # the finished runs were not started again
    assert "resumed from" in (tmp_path / "explicit_s0" / "train.log").read_text()
    assert json.loads((tmp_path / "explicit_s0" / "eval.json").read_text())["steps"] == 2


def test_the_gpu_suite_script_trains_a_settings_seeds_together_and_resumes_the_one_cut(tmp_path):
    """``TOGETHER=1``: one process per setting trains its unfinished seeds side by side (``train.together=true``),
    each in its own ``<setting>_s<seed>`` folder; after one is cut, the same command trains that one alone again."""
    root = Path(__file__).resolve().parents[1]
    tiny = "train.max_steps=2 train.eval_size=8 data.test_size=8 train.val_size=4 train.val_every=0 "
    tiny += "data.train_size=32 train.batch_size=4 train.checkpoint_every=2 train.threads=1"
    env = {**os.environ, "DEVICE": "cpu", "WORKERS": "1", "PYTHON": sys.executable, "JOBS": "1", "REPORT": "0"}
    env |= {"SEEDS": "0 1", "MODELS": "explicit", "ABLATIONS": "", "EXPERIMENT": "smoke", "TOGETHER": "1"}
    cmd = ["bash", str(root / "ablations" / "suite_gpu.sh"), str(tmp_path), *tiny.split()]
    subprocess.run(cmd, cwd=root, env=env, check=True, capture_output=True, timeout=600)
    assert sorted(p.parent.name for p in tmp_path.glob("*/eval.json")) == ["explicit_s0", "explicit_s1"]
    assert "training 2 run(s) together" in (tmp_path / "explicit.log").read_text()
    assert json.loads((tmp_path / "explicit_s1" / "status.json").read_text())["status"] == "ok"
    (tmp_path / "explicit_s1" / "eval.json").unlink()
    stamp = (tmp_path / "explicit_s0" / "eval.json").stat().st_mtime_ns
    subprocess.run(cmd, cwd=root, env=env, check=True, capture_output=True, timeout=600)
    assert (tmp_path / "explicit_s0" / "eval.json").stat().st_mtime_ns == stamp
    log = (tmp_path / "explicit.log").read_text()
    assert "training 1 run(s) together" in log and "resumed from" in log
    assert json.loads((tmp_path / "explicit_s1" / "eval.json").read_text())["steps"] == 2


@pytest.mark.slow
def test_a_compiled_run_trains_to_the_eager_runs_numbers(tmp_path):
    """``train.compile=true`` (torch.compile of the model and D) computes the same function: a tiny run's test
    metrics match the eager run's to float rounding, and its checkpoint loads into a plain model."""
    run(cfg_of(*TINY, "train.max_steps=2", "train.val_every=0"), tmp_path / "eager")
    run(cfg_of(*TINY, "train.max_steps=2", "train.val_every=0", "train.compile=true"), tmp_path / "compiled")
    eager, compiled = (json.loads((tmp_path / k / "eval.json").read_text()) for k in ("eager", "compiled"))
    for key in ("recon_mse", "normal_mean", "albedo_si_mse", "recon_face_psnr"):
        assert compiled[key] == pytest.approx(eager[key], rel=1e-3, abs=1e-5), key
    model = T.build_model(cfg_of(*TINY).model)
    model.load_state_dict(torch.load(tmp_path / "compiled" / "checkpoints" / "last.pt", weights_only=False)["model"])


def test_stacked_optimiser_state_holds_each_runs_state_and_gives_it_back():
    """Runs resumed from checkpoints train stacked from where each stood: their optimisers' state is stacked in
    (:func:`disent.stack.stacked_optimizer`) and each run's slice comes back as its own
    (:func:`disent.stack.run_slice`), the step count shared."""
    from disent.stack import run_slice, stacked_optimizer

    cfg = cfg_of(*TINY)
    nets = [torch.nn.Linear(3, 2) for _ in range(2)]
    opts = [T.make_optimizer(n, cfg.train) for n in nets]
    for k, (n, o) in enumerate(zip(nets, opts)):
        n(torch.full((4, 3), k + 1.0)).square().sum().backward()
        o.step()
    stacked = [torch.stack([n.weight.detach() for n in nets]), torch.stack([n.bias.detach() for n in nets])]
    opt = stacked_optimizer(opts, stacked, cfg.train)
    for i, o in enumerate(opts):
        mine, back = o.state_dict(), run_slice(opt.state_dict(), i)
        assert back["param_groups"] == mine["param_groups"]
        for j, state in mine["state"].items():
            assert set(back["state"][j]) == set(state)
            for key, value in state.items():
                assert torch.equal(back["state"][j][key], value), (i, j, key)
    first, other = run_slice(opt.state_dict(), 0)["state"][0], opts[1].state_dict()["state"][0]
    kept = [k for k, v in other.items() if v.dim()]  # the optimiser's running averages (not its step count)
    assert kept and not any(torch.equal(first[k], other[k]) for k in kept)  # two runs' own states, not one twice


def test_a_nonfinite_loss_in_stacked_runs_stops_them_all_and_keeps_each_ones_last_good_checkpoint(
    tmp_path, monkeypatch
):
    """``train.stack``: a term that turns non-finite in one run's slice stops the stack with the run and the term
    named, and every run keeps its own last good checkpoint (each its own weights: two seeds, two models)."""
    from disent.stack import train_stacked

    calls = {"n": 0}
    bws = L.TERM_FUNCTIONS["BWS"]

    def flaky(out, batch, c=0.75):  # under vmap: one call a step for the whole stack
        calls["n"] += 1
        v = bws(out, batch, c)
        return v * float("nan") if calls["n"] == 4 else v

    over = (*TINY, "train.epochs=3", "train.max_steps=null", "train.checkpoint_every=2", "train.stack=true")
    for seed in (0, 1):
        (tmp_path / f"s{seed}").mkdir()
    states = [T.set_up(cfg_of(*over, f"seed={seed}"), tmp_path / f"s{seed}") for seed in (0, 1)]
    initial = [s.model.state_dict()["encoder.convs.0.weight"].clone() for s in states]
    monkeypatch.setitem(L.TERM_FUNCTIONS, "BWS", flaky)
    with pytest.raises(NonFiniteLoss, match=r"'BWS' is not finite at step 3 in .*s0 .*stacked with 1 other.*step 2"):
        train_stacked(states)
    weights = []
    for seed in (0, 1):
        ck = load_checkpoint(tmp_path / f"s{seed}" / "checkpoints" / "last.pt")
        assert ck["step"] == 2 and ck["cfg"]["seed"] == seed
        assert all(torch.isfinite(v).all() for v in ck["model"].values())
        weights.append(ck["model"]["encoder.convs.0.weight"])
        assert not torch.equal(weights[-1], initial[seed])  # the run's trained slice, copied back before saving
    assert not torch.equal(*weights)
