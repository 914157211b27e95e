"""Run folders written by ``python -m disent``: find them, read them, label them.

A run folder holds ``.hydra/{config,overrides,hydra}.yaml``, ``metrics.jsonl``, ``eval.json``,
``samples/*.png``, ``checkpoints/last.pt`` and ``status.json`` (written by the Hydra callback
:class:`RunStatus`: how the job ended, with the error of a failed one).  Anything may be missing (a crashed or running
job); readers return ``None`` or empty lists then, never raise.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import yaml

RUN_ROOTS = ("outputs", "multirun")


def _load_yaml(path: Path):
    try:
        return yaml.safe_load(path.read_text()) if path.is_file() else None
    except (OSError, yaml.YAMLError):
        return None


def _load_json(path: Path):
    try:
        return json.loads(path.read_text()) if path.is_file() else None
    except (OSError, ValueError):
        return None


def read_jsonl(path: Path) -> list[dict]:
    """Records of a JSON-lines file; unreadable lines (a run killed mid-write) are skipped."""
    rows = []
    if Path(path).is_file():
        for line in Path(path).read_text().splitlines():
            try:
                rows.append(json.loads(line))
            except ValueError:
                continue
    return rows


def _get(d, dotted: str, default=None):
    for key in dotted.split("."):
        if not isinstance(d, dict) or key not in d:
            return default
        d = d[key]
    return d


def _finite(x) -> bool:
    return isinstance(x, (int, float)) and math.isfinite(x)


@dataclass
class Run:
    """One run folder and what it says about itself."""

    path: Path
    cfg: dict = field(default_factory=dict)
    overrides: list = field(default_factory=list)
    choices: dict = field(default_factory=dict)
    eval: dict | None = None
    metrics: list = field(default_factory=list)
    ended: dict | None = None

    @classmethod
    def load(cls, path) -> "Run":
        p = Path(path)
        hydra = _load_yaml(p / ".hydra" / "hydra.yaml") or {}
        return cls(path=p, cfg=_load_yaml(p / ".hydra" / "config.yaml") or {},
                   overrides=_load_yaml(p / ".hydra" / "overrides.yaml") or [],
                   choices=_get(hydra, "hydra.runtime.choices", {}) or {},
                   eval=_load_json(p / "eval.json"), metrics=read_jsonl(p / "metrics.jsonl"),
                   ended=_load_json(p / "status.json"))

    # --------------------------------------------------------------- labels
    @property
    def model(self) -> str:
        return str(_get(self.cfg, "model.name") or self.choices.get("model") or "unknown")

    @property
    def ablations(self) -> list[str]:
        """Ablation names from the overrides (``+ablation=no_bws`` or ``+ablation=[no_bws,no_adv]``)."""
        names = []
        for o in self.overrides:
            key, _, value = str(o).lstrip("+~").partition("=")
            if key == "ablation":
                names += [v.strip() for v in value.strip("[]").split(",") if v.strip()]
        listed = self.cfg.get("ablations") if isinstance(self.cfg, dict) else None
        if not names and isinstance(listed, (list, tuple)):
            names = [str(a) for a in listed]
        return sorted(set(names))

    @property
    def variant(self) -> str:
        """``model`` or ``model+ablation1+ablation2``: the row of the ablation table."""
        return "+".join([self.model, *self.ablations])

    @property
    def seed(self):
        return self.cfg.get("seed") if isinstance(self.cfg, dict) else None

    @property
    def lr(self):
        return _get(self.cfg, "train.lr") or _get(self.cfg, "train.optim.lr") or _get(self.cfg, "optim.lr")

    @property
    def adversarial(self) -> bool:
        """Whether the adversarial loss was on (its weight > 0 and no ``no_adv`` ablation)."""
        w = _get(self.cfg, "loss.adv", _get(self.cfg, "loss.weights.adv", 1.0))
        return "no_adv" not in self.ablations and bool(w)

    @property
    def checkpoint(self) -> Path | None:
        c = self.path / "checkpoints" / "last.pt"
        return c if c.is_file() else None

    # --------------------------------------------------------------- outcome
    def last(self, key: str):
        """The last finite value of ``key`` logged in ``metrics.jsonl`` (None if never)."""
        for row in reversed(self.metrics):
            if _finite(row.get(key)):
                return row[key]
        return None

    @property
    def status(self) -> str:
        """``nan`` (a loss became NaN/Inf: ``status.json`` says so, or one was logged), ``failed``
        (any other error), ``diverged`` (final total loss above 2x its first logged value),
        ``ok`` (evaluated) or ``incomplete`` (no eval.json: still running or killed)."""
        said = (self.ended or {}).get("status") or (self.eval or {}).get("status")
        if said in ("nan", "diverged", "failed"):
            return said
        key = "total" if any("total" in r for r in self.metrics) else "loss"
        losses = [r.get(key) for r in self.metrics if key in r]
        if any(not _finite(x) for x in losses):
            return "nan"
        if len(losses) >= 2 and losses[-1] > 2 * losses[0]:
            return "diverged"
        return "ok" if self.eval else "incomplete"

    def value(self, key: str):
        """A metric from eval.json, else the last logged value."""
        if self.eval and _finite(self.eval.get(key)):
            return self.eval[key]
        return self.last(key)


try:
    from hydra.experimental.callback import Callback
except ImportError:  # hydra is a dependency; this only keeps the readers importable without it
    Callback = object


class RunStatus(Callback):
    """Hydra callback: ``status.json`` in each job folder, ``{"status": ok|nan|failed, "error": ...}``.

    Registered in ``conf/config.yaml`` under ``hydra.callbacks``, so a multirun records jobs
    that stopped on a non-finite loss (``disent.train.NonFiniteLoss``) instead of losing them.
    Before anything is written, a run folder held by another live run (``disent.runs.RunLock``)
    stops the new run with one line: Hydra would otherwise overwrite that run's ``.hydra/`` config.
    """

    def on_run_start(self, config, **kwargs) -> None:
        from omegaconf import OmegaConf

        from disent.runs import lock_holder

        run_dir = OmegaConf.select(config, "hydra.run.dir")
        holder = lock_holder(run_dir) if run_dir else None
        if holder is not None:
            raise SystemExit(f"error: the run folder {run_dir} is in use by process {holder}; "
                             "give this run its own folder (hydra.run.dir=...)")

    def on_job_end(self, config, job_return, **kwargs) -> None:
        from hydra.core.utils import JobStatus

        from omegaconf import OmegaConf

        out = OmegaConf.select(job_return.hydra_cfg, "hydra.runtime.output_dir") if job_return.hydra_cfg else None
        if not out:
            return
        out = Path(out)
        if job_return.status == JobStatus.COMPLETED:
            status = {"status": "ok"}
        else:
            err = job_return._return_value
            nan = isinstance(err, FloatingPointError) or "not finite" in str(err)
            status = {"status": "nan" if nan else "failed", "error": f"{type(err).__name__}: {err}"}
        out.mkdir(parents=True, exist_ok=True)
        (out / "status.json").write_text(json.dumps(status))


def find_runs(roots=RUN_ROOTS) -> list[Run]:
    """Every run folder (one holding ``.hydra/config.yaml``) under ``roots``, sorted by path."""
    found = set()
    for root in roots:
        root = Path(root)
        if root.is_dir():
            found.update(c.parent.parent for c in root.rglob(".hydra/config.yaml"))
    return [Run.load(p) for p in sorted(found)]



def pick_runs(runs, variants=None) -> dict[str, Run]:
    """One finished run with a checkpoint per variant: the longest trained, then the lowest seed.

    ``variants`` defaults to the plain models (runs without ablations)."""
    runs = [r if isinstance(r, Run) else Run.load(r) for r in runs]
    chosen = {}

    def order(r):
        steps = r.value("steps")
        return (-(steps if isinstance(steps, (int, float)) else 0), r.seed if isinstance(r.seed, int) else 1 << 30, str(r.path))

    for r in sorted(runs, key=order):
        if r.checkpoint is None or r.status != "ok":
            continue
        if (variants is None and not r.ablations) or (variants is not None and r.variant in variants):
            chosen.setdefault(r.variant, r)
    return chosen


def load_models(runs, variants=None) -> dict:
    """``{variant: model}`` for :func:`pick_runs`; empty when ``disent.models`` is not available."""
    try:
        from disent.models import load_run
    except ImportError:
        return {}
    models = {}
    for name, r in pick_runs(runs, variants).items():
        model, _ = load_run(r.path)
        models[name] = model.eval()
    return models


__all__ = ["RUN_ROOTS", "Run", "RunStatus", "find_runs", "read_jsonl", "pick_runs", "load_models"]
