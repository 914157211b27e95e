"""Shipped weights (disent/weights/): each loads by name and reproduces its recorded test metrics;
unknown names and mismatched architectures get errors that say what is wrong."""

import json

import pytest
import torch

from disent.models import build_model, load_run
from disent.models.shipped import CHECK_IMAGES, WEIGHTS, load_weights, manifest, shipped_names
from disent.ship import add_metrics, check_metrics, ship

# The recorded check ran on one CPU; another CPU or thread count changes float rounding, never more than this.
TOLERANCE = {"recon_psnr": 0.02, "normal_mean": 0.02, "albedo_si_mse": 1e-4, "sh_error": 1e-3}
SHIPPED = shipped_names()


def test_the_three_models_are_shipped():
    assert set(SHIPPED) >= {"explicit", "implicit", "baseline"}


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_checkpoint_reproduces_its_recorded_metrics(name):
    entry = manifest()[name]
    path = WEIGHTS / entry["file"]
    assert path.stat().st_size <= 10e6, "shipped weights must stay within 10 MB"
    model, cfg = load_run(name)
    assert cfg.model.name == entry["cfg"]["model"]["name"] and model.trained_steps == entry["steps"] and model.shipped
    got = check_metrics(model, cfg, entry["check_images"])
    assert entry["check_images"] == CHECK_IMAGES and set(got) == set(entry["check"])
    for k, v in entry["check"].items():
        assert got[k] == pytest.approx(v, abs=TOLERANCE[k]), k


def test_unknown_name_lists_the_shipped_ones():
    with pytest.raises(FileNotFoundError, match="shipped models: .*explicit"):
        load_run("explicitt")


def test_architecture_mismatch_is_named(tmp_path):
    model = build_model({"name": "explicit", "resolution": 16, "code_dim": 8})
    other = build_model({"name": "explicit", "resolution": 16, "code_dim": 8, "norm": "batch"}).state_dict()
    with pytest.raises(ValueError, match="not in the model: .*norms"):
        load_weights(model, other, "x.pt")
    smaller = build_model({"name": "explicit", "resolution": 16, "code_dim": 4}).state_dict()
    with pytest.raises(ValueError, match=r"shape mismatch: .*\(4, 16\)|shape mismatch"):
        load_weights(model, smaller, "x.pt")


def test_ship_writes_half_weights_and_manifest(tmp_path):
    """ship() on a finished smoke run: float16 tensors, a manifest entry whose check equals a fresh evaluation."""
    from hydra import compose, initialize_config_dir

    from disent.ship import main as _  # noqa: F401  (the command exists)
    from disent.train import run
    from tests.test_models import CONF

    with initialize_config_dir(config_dir=CONF, version_base="1.3"):
        cfg = compose("config", overrides=["+experiment=smoke", "train.max_steps=2", "data.test_size=8"])
    run(cfg, tmp_path / "run")
    entry = ship(tmp_path / "run", "tiny", tmp_path / "weights")
    saved = torch.load(tmp_path / "weights" / "tiny.pt", weights_only=False)
    assert all(v.dtype == torch.float16 for v in saved["model"].values() if v.is_floating_point())
    listed = json.loads((tmp_path / "weights" / "manifest.json").read_text())
    assert listed["tiny"]["steps"] == 2 and listed["tiny"]["check"] == entry["check"]
    model = build_model(saved["cfg"]["model"])
    load_weights(model, saved["model"], "tiny.pt")
    from omegaconf import OmegaConf

    again = check_metrics(model.eval(), OmegaConf.create(saved["cfg"]), CHECK_IMAGES)
    assert again == pytest.approx(entry["check"])

    # metrics added later: a key the run's eval.json lacks is scored from the shipped weights and added, with a note;
    # the keys it has keep the run's values, and a second call adds nothing
    listed["tiny"]["metrics"].pop("matte_iou")
    listed["tiny"]["metrics"]["normal_mean"] = -1.0  # a marker: must survive
    (tmp_path / "weights" / "manifest.json").write_text(json.dumps(listed))
    assert add_metrics("tiny", tmp_path / "weights") == ["matte_iou"]
    tiny = manifest(tmp_path / "weights")["tiny"]
    assert 0 <= tiny["metrics"]["matte_iou"] <= 1 and tiny["metrics"]["normal_mean"] == -1.0
    assert tiny["metrics_added"]["keys"] == ["matte_iou"] and tiny["metrics_added"]["weights"] == "float16"
    assert add_metrics("tiny", tmp_path / "weights") == []
    # a later addition keeps the revision of each one
    listed = manifest(tmp_path / "weights")
    listed["tiny"]["metrics"].pop("pseudo_matte_iou")
    (tmp_path / "weights" / "manifest.json").write_text(json.dumps(listed))
    assert add_metrics("tiny", tmp_path / "weights") == ["pseudo_matte_iou"]
    added = manifest(tmp_path / "weights")["tiny"]["metrics_added"]
    assert added["keys"] == ["matte_iou", "pseudo_matte_iou"]
    assert [a["keys"] for a in added["additions"]] == [["matte_iou"], ["pseudo_matte_iou"]]
    assert all(a["git"] for a in added["additions"])  # each addition says at what revision
    with pytest.raises(FileNotFoundError, match="shipped models: tiny"):
        add_metrics("tinyy", tmp_path / "weights")
