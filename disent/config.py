"""A run's settings: the checks a config passes before anything runs, which settings define a run (and so must
match to resume it or to share its table row), what a config from before a setting existed trains as, and which
settings a model has no use for.  Below the training loop; the run catalogue (:mod:`disent.runs`) labels runs
with it."""

from __future__ import annotations

import functools
import json
import math

import torch

from disent import losses as L
from disent.models import build_model

OPTIMIZERS = {"rmsprop": torch.optim.RMSprop, "adam": torch.optim.Adam}
SCHEDULES = ("epoch_decay", "cosine")
NETWORK_TARGETS = ("sh_network", "sh_network_texture")  # E_recon-L targets drawn through loss.recon_L_network


def loss_setting(cfg_loss, key: str):
    """``loss.<key>`` of a run's config; for a config from before the key existed, the value that trains as such a
    run trained (:data:`ADDED_LATER`)."""
    return cfg_loss.get(key, ADDED_LATER[f"loss.{key}"])


def truth_readers(cfg_loss) -> list[str]:
    """The loss settings that read SynthFaces' true layers: a ceiling term that is on, or E_recon-L on the true light
    (``loss.recon_L_target=sh``, ``loss.recon_L_oracle_mix`` above 0)."""
    readers = [f"loss.weights.{t}" for t in L.TRUTH if cfg_loss.weights.get(t, 0)]
    if loss_setting(cfg_loss, "recon_L_target") == "sh":
        readers.append("loss.recon_L_target=sh")
    if mix := loss_setting(cfg_loss, "recon_L_oracle_mix"):
        readers.append(f"loss.recon_L_oracle_mix={mix}")
    return readers


class ConfigError(ValueError):
    """A setting that cannot run, named with the values it accepts; raised before anything is written."""


def check_config(cfg) -> None:
    """Every training setting a run needs, checked before it starts (``ConfigError`` names the key)."""
    t, d = cfg.train, cfg.data

    def whole(key, value, minimum=1, optional=False):
        if optional and value is None:
            return
        if isinstance(value, bool) or not isinstance(value, int) or value < minimum:
            raise ConfigError(
                f"{key}={value!r}: must be a whole number >= {minimum}" + (" or null" if optional else "")
            )

    whole("train.batch_size", t.batch_size)
    whole("train.epochs", t.epochs)
    whole("train.max_steps", t.max_steps, optional=True)
    whole("train.stop_step", t.get("stop_step"), optional=True)
    whole("train.threads", t.threads, minimum=0)
    whole("data.train_size", d.get("train_size"), optional=True)
    whole("data.test_size", d.get("test_size"), optional=True)
    if isinstance(t.lr, bool) or not isinstance(t.lr, (int, float)) or not t.lr > 0:
        raise ConfigError(f"train.lr={t.lr!r}: must be a positive number")
    for key, value, allowed in (
        ("train.optimizer", t.get("optimizer", "rmsprop"), OPTIMIZERS),
        ("train.schedule", t.get("schedule", "epoch_decay"), SCHEDULES),
        ("loss.recon_L_target", loss_setting(cfg.loss, "recon_L_target"), L.RECON_L_TARGETS),
        ("loss.recon_L_scale", loss_setting(cfg.loss, "recon_L_scale"), L.RECON_L_SCALES),
    ):
        if value not in allowed:
            raise ConfigError(f"{key}={value!r}; choose from {', '.join(allowed)}")
    whole("loss.early_steps", loss_setting(cfg.loss, "early_steps"), minimum=0)
    early = loss_setting(cfg.loss, "early_weights") or {}
    for term, w in early.items():
        if term not in cfg.loss.weights:
            raise ConfigError(f"loss.early_weights.{term}: no such term; terms are {', '.join(cfg.loss.weights)}")
        if isinstance(w, bool) or not isinstance(w, (int, float)) or not (math.isfinite(w) and w >= 0):
            raise ConfigError(f"loss.early_weights.{term}={w!r}: must be a finite number >= 0")
    for key in ("recon_L_oracle_mix", "recon_L_network_share"):
        share = loss_setting(cfg.loss, key)
        if isinstance(share, bool) or not isinstance(share, (int, float)) or not 0 <= share <= 1:
            raise ConfigError(f"loss.{key}={share!r}: must be a number in [0, 1]")
    if loss_setting(cfg.loss, "recon_L_target") in NETWORK_TARGETS:
        network = loss_setting(cfg.loss, "recon_L_network")
        from disent.models import load_run

        try:
            load_run(str(network))
        except Exception as e:
            raise ConfigError(f"loss.recon_L_network={network!r}: no model to load ({e})") from e
    if (readers := truth_readers(cfg.loss)) and d.name != "synth":
        raise ConfigError(f"{', '.join(readers)} read(s) the true layers, which only data=synth has")
    norms = (
        ("recon_p", "1 (L1, the release), 2 (L2, the paper)"),
        ("recon_fg_p", "1 (L1), 2 (L2, the release)"),
        ("matte_p", "1 (L1, the release), 2 (L2, the paper)"),
    )
    for key, what in norms:
        if cfg.loss.get(key, 2) not in (1, 2):
            raise ConfigError(f"loss.{key}={cfg.loss[key]!r}; choose from {what}")
    check_device("device", cfg.device)
    if (data_device := d.get("device", "cpu")) != "cpu":
        check_device("data.device", data_device)
        if d.name != "synth":
            raise ConfigError(f"data.device={data_device!r}: only SynthFaces (data=synth) renders on a device")


def check_device(key: str, device) -> None:
    """``cpu``, ``cuda`` or ``cuda:N``, where this torch and machine have it."""
    device = str(device)
    kind, _, index = device.partition(":")
    if kind not in ("cpu", "cuda") or (index and not index.isdigit()) or (kind == "cpu" and index):
        raise ConfigError(f"{key}={device!r}; choose from cpu, cuda, cuda:N")
    if kind == "cuda" and not torch.cuda.is_available():
        raise ConfigError(
            f"{key}={device!r}, but this torch ({torch.__version__}) sees no CUDA GPU; use {key}=cpu, "
            "or install a CUDA build of torch (README, GPU install)"
        )
    if kind == "cuda" and index and int(index) >= torch.cuda.device_count():
        raise ConfigError(f"{key}={device!r}: this machine has {torch.cuda.device_count()} CUDA device(s)")


# Settings that define what a checkpoint is: resuming under other values (without resume_force) is refused.
# Budget and bookkeeping (max_steps, epochs, time limit, threads, logging, device) may change between sessions.
RUN_DEFINING = (
    "seed",
    "init",
    "model",
    "data",
    "loss",
    "train.batch_size",
    "train.optimizer",
    "train.lr",
    "train.schedule",
    "train.lr_decay",
    "train.warmup_steps",
    "train.amp",
)
# what a run is, apart from its seed, for the report's settings (disent.runs.setting): with its budget
SETTING_KEYS = tuple(k for k in RUN_DEFINING if k != "seed") + ("train.max_steps", "train.epochs")
NOT_DEFINING = ("data.test_size", "model.kernels", "data.device")  # evaluation only; the same function computed another
# way (kernels; data.device: the same faces rendered elsewhere, equal to float rounding)
# settings added after runs existed, each with the value that trains as those runs did
ADDED_LATER = {
    "init": None,
    "loss.recon_p": 2,
    "loss.recon_fg_p": 2,
    "loss.matte_p": 2,
    "loss.lhat_gray": False,
    "loss.lhat_white": True,
    "loss.recon_L_space": "shading",
    "loss.recon_L_target": "sh_pseudo",
    "loss.recon_L_oracle_mix": 0.0,
    "loss.recon_L_scale": "target",
    "loss.recon_L_network": "explicit",
    "loss.recon_L_network_share": 0.6,
    "loss.early_steps": 0,
    "loss.early_weights": {},
    "model.decoder_convs": 1,
    "data.device": "cpu",
    **{f"loss.weights.{t}": 0.0 for t in L.TRUTH},
}


class _Absent:
    def __repr__(self):
        return "absent"


ABSENT = _Absent()  # a key that one config lacks (and ADDED_LATER does not know)


def check_init(cfg, init_cfg: dict | None) -> None:
    """A warm start's model settings (``init_cfg``: its checkpoint's config) must be ``cfg.model``'s, ``kernels``
    aside (the same function computed another way); a setting added since counts as those runs trained."""
    from omegaconf import OmegaConf

    before = {k.removeprefix("model."): v for k, v in ADDED_LATER.items() if k.startswith("model.")}
    theirs = {**before, **((init_cfg or {}).get("model") or {})}
    ours = {**before, **OmegaConf.to_container(cfg.model, resolve=True)}
    differ = sorted(k for k in {*theirs, *ours} if f"model.{k}" not in NOT_DEFINING and theirs.get(k) != ours.get(k))
    if differ:
        raise ConfigError(
            f"init={cfg.init}: its model differs from this run's in "
            + "; ".join(f"model.{k} {theirs.get(k)!r} there, {ours.get(k)!r} here" for k in differ)
        )


@functools.lru_cache(maxsize=None)
def _model_outputs(model_json: str) -> frozenset:
    """The output names of a model config's forward pass (one black image, eval mode)."""
    cfg = json.loads(model_json)
    model = build_model(cfg).eval()
    res = cfg.get("resolution", 64)
    with torch.no_grad():
        return frozenset(model(torch.zeros(1, 3, res, res)))


def idle_settings(cfg: dict | None) -> frozenset:
    """``loss.weights.T`` of each term the config's model cannot compute (it lacks the output the term needs,
    :data:`disent.losses.NEEDS`: E_recon-N for the baseline), and the loss settings that act only through such
    terms or terms weighted 0 (:func:`disent.losses.term_settings`: c without BWS and without the whitened L-hat
    target, ``+ablation=no_bws``), and an early weight (``loss.early_weights``) of a missing term, equal to the
    term's weight or given no early steps (and ``loss.early_steps`` with no early weight left): they never reach
    training, so they do not define the run."""
    model = (cfg or {}).get("model")
    if not isinstance(model, dict) or "name" not in model:
        return frozenset()
    outputs = _model_outputs(json.dumps(model, sort_keys=True))
    missing = {t for t, needed in L.NEEDS.items() if needed not in outputs}
    loss = cfg.get("loss") or {}
    weights = loss.get("weights") or {}
    off = missing | {t for t, w in weights.items() if w == 0}
    by_term = {k: ts for k, ts in L.term_settings(loss.get("lhat_white", True)).items() if off.issuperset(ts)}
    early = loss.get("early_weights") or {}  # an early weight of a missing term, or one its weight repeats, or none
    idle_early = {t for t, w in early.items() if t in missing or w == weights.get(t) or not loss.get("early_steps")}
    return frozenset(
        [f"loss.weights.{t}" for t in missing]
        + [f"loss.{k}" for k in by_term]
        + [f"loss.early_weights.{t}" for t in idle_early]
        + (["loss.early_steps"] if idle_early == set(early) else [])
    )


def config_changes(old: dict | None, new: dict, keys=RUN_DEFINING, ignore=frozenset()) -> dict:
    """``{key: (old, new)}`` for each leaf under ``keys`` (less ``ignore``) whose value differs between two resolved
    configs; a key one of them lacks reads as its ``ADDED_LATER`` value, else as ``ABSENT``."""

    def leaves(d, prefix=""):
        if isinstance(d, dict):
            return {k: v for key, sub in d.items() for k, v in leaves(sub, f"{prefix}{key}.").items()}
        return {prefix[:-1]: d}

    a, b = ({**ADDED_LATER, **leaves(d or {})} for d in (old, new))  # absent: the value before it existed
    under = lambda k: any(k == key or k.startswith(key + ".") for key in keys)  # noqa: E731
    return {
        k: (a.get(k, ABSENT), b.get(k, ABSENT))
        for k in sorted(set(a) | set(b))
        if under(k) and k not in NOT_DEFINING and k not in ignore and a.get(k, ABSENT) != b.get(k, ABSENT)
    }


def config_differences(old: dict | None, new: dict, keys=RUN_DEFINING, ignore=frozenset()) -> list[str]:
    """``key: old -> new`` for each leaf under ``keys`` (less ``ignore``) whose value differs between two resolved
    configs."""
    return [f"{k}: {a!r} -> {b!r}" for k, (a, b) in config_changes(old, new, keys, ignore).items()]
