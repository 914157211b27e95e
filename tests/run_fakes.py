"""Tiny fake run folders for the tests of the run catalogue and the report (no training)."""

import json

import yaml

from disent.runs import composed_config


def make_run(
    root, name, model="explicit", ablations=(), seed=0, losses=(3.0, 2.0, 1.0), eval_=None, ips=500.0, extra=()
):
    d = root / name
    (d / ".hydra").mkdir(parents=True)
    ov = [f"model={model}", f"seed={seed}", *extra] + ([f"+ablation=[{','.join(ablations)}]"] if ablations else [])
    cfg = composed_config(tuple(ov))  # what training resolves with these overrides
    (d / ".hydra" / "config.yaml").write_text(yaml.safe_dump(cfg))
    (d / ".hydra" / "overrides.yaml").write_text(yaml.safe_dump(ov))
    (d / ".hydra" / "hydra.yaml").write_text(
        yaml.safe_dump({"hydra": {"runtime": {"choices": {"model": model, "experiment": "smoke"}}}})
    )
    rows = [{"step": i, "total": l, "images_per_s": ips} for i, l in enumerate(losses)]  # what training logs
    (d / "metrics.jsonl").write_text(
        "".join(json.dumps(r) + "\n" for r in rows) + '{"step": 9, "total"'
    )  # torn last line
    if eval_ is not None:
        (d / "eval.json").write_text(json.dumps(eval_))
    return d


def fake_suite(root):
    smoke = ("+experiment=smoke",)
    make_run(root, "0", "baseline", eval_={"recon_mse": 0.01}, ips=900, extra=smoke)
    ev = {"recon_mse": 0.02, "normal_mean": 20.0, "pseudo_normal_mean": 15.0}
    make_run(root, "1", "explicit", seed=0, eval_=ev, extra=smoke)
    ev = {"recon_mse": 0.04, "normal_mean": 22.0, "pseudo_normal_mean": 15.0}
    make_run(root, "2", "explicit", seed=1, eval_=ev, extra=smoke)
    make_run(root, "3", "explicit", ["no_bws"], eval_={"recon_mse": 0.03, "normal_mean": 30.0}, ips=700, extra=smoke)
    make_run(root, "4", "explicit", ["no_adv"], losses=(1.0, None), extra=smoke)  # NaN logged as null
    make_run(root, "5", "implicit", losses=(1.0, 5.0), extra=smoke)  # diverged, never evaluated
    make_run(root, "6", "implicit", extra=smoke)  # still running: incomplete
