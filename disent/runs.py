"""The run catalogue: the readers that find, read and label finished runs (a run folder is Hydra's
``outputs/<date>/<time>-<pid>/``; what training writes into it is :mod:`disent.storage`), from their folders or
from their rows of ``reports/runs.jsonl`` (written by :mod:`disent.publish`).

A run folder holds ``.hydra/{config,overrides,hydra}.yaml`` (Hydra), ``eval.json`` and ``status.json`` (the Hydra
callback :class:`RunStatus`: how the job ended, with the error of a failed one) beside what :mod:`disent.storage`
writes.

Read: :class:`Run`, :func:`find_runs`, :func:`pick_runs`, :func:`load_models`.  Anything may be missing (a
crashed or running job); readers return ``None`` or empty lists then, never raise.

Kept: :func:`disent.publish.write_records` keeps each ended run as one row of ``reports/runs.jsonl`` (its config,
overrides, eval, status, revision and machine, and its learning curve thinned to what the report draws; no weights, no
path), so that the report's tables and curves outlive the run folders.  A run is named by a short stable id
(:func:`run_id`, a hash of the folder it trained in), never by that folder; :func:`find_runs` reads a row like a run
folder and prefers the folder itself.
"""

from __future__ import annotations

import copy
import functools
import io
import json
import math
import os
import shutil
import subprocess
from dataclasses import dataclass, field
from pathlib import Path

import yaml
from omegaconf import OmegaConf

from disent.storage import (
    GIT_LINE,
    NO_REVISION,
    dotted,
    load_json,
    load_yaml,
    lock_holder,
    read_jsonl,
)

# ----------------------------------------------------------------------------- reading runs
RUN_ROOTS = ("outputs", "multirun")
RECORDS = "runs.jsonl"  # in reports/: one row per ended run the report has read (write_records)


def run_id(origin) -> str:
    """A run's short stable id: the first 6 hex digits of the SHA-1 of the folder it trained in (as a string)."""
    import hashlib

    return hashlib.sha1(str(origin).encode()).hexdigest()[:6]


def folder_id(path) -> str:
    """The id of the run that trained in folder ``path`` (:func:`run_id` of its resolved path): one id whether the
    path is typed relative, through a symlink or as the record kept it."""
    return run_id(Path(path).resolve())


def run_ref(value) -> str | None:
    """The run id that a tool's ``run`` field names: ``run:ID`` as published, or a run folder's path (an id is
    computed from it); None for anything else (a shipped model's name)."""
    text = str(value or "")
    if text.startswith("run:"):
        return text[4:]
    return folder_id(text) if text.startswith(("/", ".")) or os.sep in text else None


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
    machine: dict | None = None  # machine.json: what it trained on (runs of older versions lack it)
    retyped: list | None = None  # retyped_overrides, once computed
    idle: frozenset | None = None  # idle_keys, once computed
    record: dict | None = None  # the row of reports/runs.jsonl this run was read from (None: a run folder)

    @classmethod
    def load(cls, path) -> "Run":
        p = Path(path)
        hydra = load_yaml(p / ".hydra" / "hydra.yaml") or {}
        return cls(
            path=p,
            cfg=load_yaml(p / ".hydra" / "config.yaml") or {},
            overrides=load_yaml(p / ".hydra" / "overrides.yaml") or [],
            choices=dotted(hydra, "hydra.runtime.choices", {}) or {},
            eval=load_json(p / "eval.json"),
            metrics=read_jsonl(p / "metrics.jsonl"),
            ended=load_json(p / "status.json"),
            machine=load_json(p / "machine.json"),
        )

    @classmethod
    def from_record(cls, row: dict) -> "Run":
        """A run as its row of ``reports/runs.jsonl`` (:func:`record_row`) keeps it."""
        return cls(
            path=Path(f"run:{row['id']}"),
            cfg=row.get("config") or {},
            overrides=row.get("overrides") or [],
            choices=row.get("choices") or {},
            eval=row.get("eval"),
            metrics=row.get("curve") or [],
            ended=row.get("ended"),
            machine=row.get("machine"),
            record=row,
        )

    @property
    def id(self) -> str:
        """The run's short stable id (:func:`run_id` of the folder it trained in)."""
        return self.record["id"] if self.record else folder_id(self.path)

    @property
    def name(self) -> str:
        """How a page names the run: its variant, seed and id (``explicit+no_bws s1 #3fa2c1``)."""
        return f"{self.variant} s{self.seed} #{self.id}"

    @property
    def recipe(self) -> bool:
        """A run of the training recipe's leave-one-out (ablations/recipe.sh writes them under a ``recipe/`` folder)."""
        return bool(self.record.get("recipe")) if self.record else "recipe" in self.path.resolve().parts[:-1]

    @property
    def revision(self) -> str | None:
        """The git revision the run trained at (``git.txt``, :func:`git_revision`), None where it has none."""
        if self.record:
            return self.record.get("revision")
        try:
            first = (self.path / "git.txt").read_text().split("\n", 1)[0]
        except OSError:
            return None
        rev = first.removeprefix(GIT_LINE).strip() if first.startswith(GIT_LINE) else None
        return None if rev == NO_REVISION else rev

    # --------------------------------------------------------------- labels
    @property
    def model(self) -> str:
        return str(dotted(self.cfg, "model.name") or self.choices.get("model") or "unknown")

    @property
    def ablations(self) -> list[str]:
        """Ablation names from the overrides (``+ablation=no_bws`` or ``+ablation=[no_bws,no_adv]``)."""
        names = []
        for o in self.overrides:
            key, _, value = str(o).lstrip("+~").partition("=")
            if key == "ablation":
                names += [v.strip() for v in value.strip("[]").split(",") if v.strip()]
        return sorted(set(names))

    @property
    def ceiling(self) -> bool:
        """A supervised-ceiling run (``loss=ceiling``): trained on the true layers, not on the paper's objective."""
        from disent.losses import TRUTH

        return any(dotted(self.cfg, f"loss.weights.{t}", 0) for t in TRUTH)

    @property
    def light_oracle(self) -> bool:
        """E_recon-L's target draws on the scene's true light (``loss.recon_L_target=sh`` or an oracle dose
        ``loss.recon_L_oracle_mix`` > 0): a measurement of what a better L-hat buys, not the paper's model."""
        from disent.config import truth_readers

        loss = OmegaConf.create({"weights": {}, **(dotted(self.cfg, "loss") or {})})
        return any(not r.startswith("loss.weights.") for r in truth_readers(loss))  # not a ceiling term

    @property
    def plain(self) -> bool:
        """The paper's model as configured: no ablation, not a ceiling run."""
        return not self.ablations and not self.ceiling

    @property
    def variant(self) -> str:
        """``model`` or ``model+ablation1+ablation2`` (the ablation table's rows); ``model+ceiling``: a ceiling run."""
        return "+".join([self.model, *self.ablations, *(["ceiling"] if self.ceiling else [])])

    @property
    def seed(self):
        return self.cfg.get("seed") if isinstance(self.cfg, dict) else None

    @property
    def lr(self):
        return dotted(self.cfg, "train.lr")

    @property
    def adversarial(self) -> bool:
        """Whether the adversarial loss was on (its weight > 0 and no ``no_adv`` ablation)."""
        w = dotted(self.cfg, "loss.weights.adv", 1.0)
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
        said = (self.ended or {}).get("status")
        if self.record and "status" in self.record:  # read from the whole log when the row was written
            return self.record["status"]
        if said in ("nan", "diverged", "failed"):
            return said
        losses = [r.get("total") for r in self.metrics if "total" in r]
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
    Before anything is written, a run folder held by another live run (``disent.storage.RunLock``)
    stops the new run with one line: Hydra would otherwise overwrite that run's ``.hydra/`` config.
    """

    def on_run_start(self, config, **kwargs) -> None:
        from omegaconf import OmegaConf

        run_dir = OmegaConf.select(config, "hydra.run.dir")
        holder = lock_holder(run_dir) if run_dir else None
        if holder is not None:
            raise SystemExit(
                f"error: the run folder {run_dir} is in use by process {holder}; "
                "give this run its own folder (hydra.run.dir=...)"
            )

    def on_job_end(self, config, job_return, **kwargs) -> None:
        from hydra.core.utils import JobStatus
        from omegaconf import OmegaConf

        out = OmegaConf.select(job_return.hydra_cfg, "hydra.runtime.output_dir") if job_return.hydra_cfg else None
        if not out:
            return
        together = OmegaConf.select(job_return.cfg, "train.together") if job_return.cfg else False
        if job_return.status == JobStatus.COMPLETED and together and job_return._return_value is None:
            write_status(Path(out), None, "queued")  # set up; trained at the sweep's end (disent.together)
        else:
            write_status(Path(out), None if job_return.status == JobStatus.COMPLETED else job_return._return_value)

    def on_multirun_end(self, config, **kwargs) -> None:
        """The jobs a sweep with ``train.together=true`` set up, trained side by side now; each one's status."""
        from disent.together import train_queued

        for run_dir, result in train_queued():
            write_status(run_dir, result if isinstance(result, BaseException) else None)


def write_status(run_dir: Path, error: BaseException | None, status: str = "ok") -> None:
    """``status.json``: ``status`` (ok, queued) where ``error`` is None, else nan (a non-finite loss) or failed, with
    the error."""
    if error is not None:
        nan = isinstance(error, FloatingPointError) or "not finite" in str(error)
        status = {"status": "nan" if nan else "failed", "error": f"{type(error).__name__}: {error}"}
    else:
        status = {"status": status}
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "status.json").write_text(json.dumps(status))


def find_runs(roots=RUN_ROOTS, records=None) -> list[Run]:
    """Every run folder (one holding ``.hydra/config.yaml``) under ``roots`` and every row of the records file
    ``records`` (``reports/runs.jsonl``), sorted by run id (:func:`with_records`)."""
    found = set()
    for root in roots:
        root = Path(root)
        if root.is_dir():
            found.update(c.parent.parent for c in root.rglob(".hydra/config.yaml"))
    return with_records([Run.load(p) for p in found], records)


def with_records(folders: list[Run], records=None) -> list[Run]:
    """``folders`` (runs read from their folders) and the rows of ``records`` that are none of them, sorted by run
    id, so that a run keeps its place in tables and figures once only its row is left; a run found both as its
    folder and as a row is read once, from its folder."""
    ids = {r.id for r in folders}
    rows = [Run.from_record(row) for row in read_jsonl(records) if row["id"] not in ids] if records else []
    return sorted([*folders, *rows], key=lambda r: r.id)


TRAIN_SPEED_KEY = "images_per_s"  # logged by every training step (metrics.jsonl)


def run_speed(run: Run, key: str) -> float | None:
    """Median of the values logged under ``key`` (training speed is logged per step; a record keeps the median of
    its whole log), else eval.json's."""
    if run.record and key == TRAIN_SPEED_KEY and run.record.get(key) is not None:
        return float(run.record[key])
    logged = sorted(r[key] for r in run.metrics if isinstance(r.get(key), (int, float)))
    if logged:
        return float(logged[len(logged) // 2])
    v = run.value(key)
    return None if v is None else float(v)


def portable(value):
    """``value`` with each run folder's path in it (a string) replaced by ``run:ID`` (:func:`run_id`): what a record
    or a published file may say of another run."""
    if isinstance(value, dict):
        return {k: portable(v) for k, v in value.items()}
    if isinstance(value, list):
        return [portable(v) for v in value]
    if isinstance(value, str) and value.startswith("/") and not value.startswith("/dev/"):  # a run folder
        return f"run:{folder_id(value)}"
    if isinstance(value, str) and "=/" in value:  # an override naming a folder: loss.recon_L_network=/path
        key, _, path = value.partition("=")
        return f"{key}=run:{folder_id(path)}"
    return value


# overrides that do not change what a run is (its seed, bookkeeping, the CPU time guard of a budget rung)
SEED_FREE = ("seed=", "train.progress=", "train.time_limit_min=", "train.stop_step=", "resume", "hydra.")
CONF_DIR = Path(__file__).resolve().parent.parent / "conf"


@functools.lru_cache(maxsize=1)
def model_names() -> tuple[str, ...]:
    """The models ``conf/model/`` defines."""
    return tuple(sorted(p.stem for p in (CONF_DIR / "model").glob("*.yaml")))


def config_group(override) -> bool:
    """An override that picks a config group of the run (``model=implicit``, ``+ablation=no_bws``), not a value
    and not Hydra's own (``hydra/launcher=``)."""
    key = str(override).lstrip("+~").partition("=")[0]
    return "." not in key and not key.startswith("hydra") and (CONF_DIR / key).is_dir()


@functools.lru_cache(maxsize=1)
def default_groups() -> frozenset:
    """conf/config.yaml's default choices as overrides (``model=explicit``): typed or not, the same run."""
    defaults = yaml.safe_load((CONF_DIR / "config.yaml").read_text())["defaults"]
    return frozenset(f"{k}={v}" for d in defaults if isinstance(d, dict) for k, v in d.items())


def composed_config(groups: tuple) -> dict:
    """The resolved config that ``python -m disent GROUPS...`` trains with, from today's ``conf/`` (a copy)."""
    return copy.deepcopy(_composed(tuple(groups)))


@functools.lru_cache(maxsize=64)
def _composed(groups: tuple, conf_dir: str = str(CONF_DIR)) -> dict:
    from hydra import compose, initialize_config_dir

    with initialize_config_dir(config_dir=conf_dir, version_base="1.3"):
        return OmegaConf.to_container(compose(config_name="config", overrides=list(groups)), resolve=True)


@functools.lru_cache(maxsize=8)
def conf_at(revision: str) -> str | None:
    """The folder of ``conf/`` as git revision ``revision`` had it (extracted once into a temporary folder that
    is removed when the process exits), or None where git cannot give it (no repository, an unknown revision)."""
    import atexit
    import tarfile
    import tempfile

    root = CONF_DIR.parent
    try:
        tar = subprocess.run(
            ["git", "-C", str(root), "archive", revision, "conf"], capture_output=True, check=True, timeout=60
        ).stdout
    except (OSError, subprocess.SubprocessError):
        return None
    out = Path(tempfile.mkdtemp(prefix=f"conf-{revision}-"))
    atexit.register(shutil.rmtree, out, ignore_errors=True)
    with tarfile.open(fileobj=io.BytesIO(tar)) as t:
        t.extractall(out, filter="data")
    return str(out / "conf")


def typed(value) -> str:
    """A config value as an override writes it."""
    return "null" if value is None else str(value).lower() if isinstance(value, bool) else str(value)


def retyped_overrides(run: Run) -> list[str]:
    """What one types today to train ``run`` again (seed and bookkeeping aside), sorted: its config-group choices
    (always ``model=``; ``+experiment=``, ``+ablation=``, ``loss=`` where not the default) and ``key=value`` for
    each setting that defines a run (``SETTING_KEYS``) whose value differs from what those choices give with
    today's ``conf/``: an override it was given, or a default changed since it trained; an override that repeats
    today's default is none, and so is a loss weight the model has no term for (:func:`idle_keys`); a key that
    today's ``conf/`` lacks (an entry of ``loss.early_weights``) is written ``+key=value``, as Hydra takes it.
    Where today's ``conf/`` cannot compose its choices or its config cannot be
    resolved: its overrides as typed."""
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    from disent.config import ABSENT, SETTING_KEYS, config_changes

    if not run.cfg:  # no resolved config recorded: nothing to compare
        return sorted(str(o) for o in run.overrides)
    groups = sorted(
        {*(str(o) for o in run.overrides if config_group(o) and str(o) not in default_groups()), f"model={run.model}"}
    )
    try:
        today = _composed(tuple(groups))  # read only: no copy
        trained = OmegaConf.to_container(OmegaConf.create(run.cfg), resolve=True)
    except (HydraException, OmegaConfBaseException):
        return sorted(str(o) for o in run.overrides)
    changes = config_changes(trained, today, SETTING_KEYS, idle_keys(run)).items()
    return sorted(groups + [override_token(k, old, new) for k, (old, new) in changes if old is not ABSENT])


def override_token(key: str, value, today) -> str:
    """``key=value`` as one types it today, where ``today`` is the key's value in today's ``conf/``: ``+key=value``
    where conf/ lacks the key (Hydra's form for adding one: an entry of ``loss.early_weights``), a whole number
    written as a float where conf/ holds a float (:func:`as_type`)."""
    from disent.config import ABSENT

    return f"{'+' * (today is ABSENT)}{key}={typed(as_type(value, today))}"


def as_type(value, like):
    """``value`` as a float where ``like`` (today's value of its key) is one: ``loss.weights.UV=1`` typed on the
    command line (an int) and ``UV: 1.0`` in a yaml train the same, so they are one setting."""
    plain_int = isinstance(value, int) and not isinstance(value, bool)
    return float(value) if plain_int and isinstance(like, float) else value


@functools.lru_cache(maxsize=256)
def retyped_label(label: str, then: str | None = None, model: str | None = None) -> str:
    """A setting label (:func:`setting`) that a report published against the ``conf/`` of git revision ``then``,
    read against today's: each default changed since (under the label's config-group choices) that the label does
    not set is added at its value then (``loss.weights.UV=1.0`` once E_UV's default moved to 10), where the run's
    model uses it (``model``, or the label's ``model=``; unknown: where every model uses it); then each
    ``key=value`` that repeats today's default is dropped (a default has changed to it since), so the label names
    the setting as :func:`setting` names it now.  Unchanged where today's ``conf/`` cannot compose the choices;
    without ``then`` (or where git cannot give it) only the second step."""
    from hydra.errors import HydraException

    from disent.config import ABSENT, SETTING_KEYS, config_changes, idle_settings

    tokens = [t for t in label.split() if t != "(defaults)"]
    groups = tuple(sorted(t for t in tokens if config_group(t)))
    try:
        today = _composed(groups)
    except HydraException:
        return label
    then_dir = conf_at(then) if then else None
    if then_dir is not None:
        given = {t.lstrip("+~").partition("=")[0] for t in tokens}
        models = [model or next((t.split("=")[1] for t in tokens if t.startswith("model=")), None)]
        if models == [None]:
            models = model_names()
        try:
            was = _composed(groups, then_dir)
            unmodelled = tuple(g for g in groups if not g.startswith("model="))
            idle = set().union(*(idle_settings(_composed(unmodelled + (f"model={m}",))) for m in models))
        except HydraException:
            was = None
        for key, (old, new) in (config_changes(was, today, SETTING_KEYS, idle) if was else {}).items():
            if key not in given and old is not ABSENT:
                tokens.append(override_token(key, old, new))

    def today_value(token: str):
        node = today
        for part in token.lstrip("+~").partition("=")[0].split("."):
            if not isinstance(node, dict) or part not in node:
                return ABSENT
            node = node[part]
        return node

    def repeats_today(token: str) -> bool:
        value, node = token.partition("=")[2], today_value(token)
        try:  # 10 typed and 10.0 in conf/: one value
            return node is not ABSENT and typed(as_type(yaml.safe_load(value), node)) == typed(node)
        except yaml.YAMLError:
            return typed(node) == value

    def added(token: str) -> str:  # a key today's conf/ lacks is typed +key=value
        return "+" + token if token[0] not in "+~" and "=" in token and today_value(token) is ABSENT else token

    kept = sorted(added(t) if not config_group(t) else t for t in tokens if config_group(t) or not repeats_today(t))
    return " ".join(kept) or "(defaults)"


def defining_overrides(run: Run, drop=SEED_FREE) -> list[str]:
    """:func:`retyped_overrides` without those starting with ``drop``."""
    if run.retyped is None:
        run.retyped = retyped_overrides(run)
    return [o for o in run.retyped if not o.lstrip("+~").startswith(drop)]


def setting(run: Run, drop_model: bool = False, drop: tuple = ()) -> str:
    """What a run is, apart from its seed (and its model, for comparisons across models): what one types today
    to train it again (:func:`defining_overrides`).  ``drop``: more override prefixes to leave out
    (``("ablation=",)``: the setting of the full model it ablates)."""
    tokens = portable(defining_overrides(run, SEED_FREE + (("model=",) if drop_model else ()) + drop))
    return " ".join(tokens) or "(defaults)"


def measured_setting(info: dict, loaded: dict | None = None) -> str | None:
    """The setting of a run that a tool measured (its ``run``: a folder or ``run:ID``, and ``setting``), read
    against today's ``conf/`` from the run's folder or record (``loaded``: runs by id, records among them, so none
    is read twice); ``shipped`` for a shipped model.  None where neither is left."""
    if info.get("setting") in (None, "shipped"):
        return info.get("setting", "shipped")
    ref = run_ref(info.get("run"))
    run = (loaded or {}).get(ref)
    folder = Path(str(info.get("run", "")))
    if run is None and (folder / ".hydra" / "config.yaml").is_file():
        run = Run.load(folder)
    return setting(run, drop_model=True) if run is not None else None


def idle_keys(run: Run) -> frozenset:
    """The settings ``run``'s model has no use for (:func:`disent.config.idle_settings`), computed once; none without
    a config."""
    from omegaconf.errors import OmegaConfBaseException

    from disent.config import idle_settings

    if run.idle is None:
        try:
            run.idle = idle_settings(OmegaConf.to_container(OmegaConf.create(run.cfg or {}), resolve=True))
        except (OmegaConfBaseException, TypeError, ValueError, KeyError):  # an old or unresolvable config
            run.idle = frozenset()
    return run.idle


def joins(run: Run, mine: str, label: str) -> bool:
    """Whether ``run``, of setting ``mine``, trains as the runs of setting ``label`` do: the two differ only in
    settings ``run`` has no use for (:func:`idle_keys`: the baseline has no rendering terms, a run without BWS or
    the whitened L-hat no c), so it trained the same under any value of them."""
    idle = idle_keys(run)
    kept = [o for o in label.split() if o != "(defaults)" and o.lstrip("+~").split("=", 1)[0] not in idle]
    return label != mine and bool(idle) and (" ".join(kept) or "(defaults)") == mine


def group_by_setting(runs, drop: tuple = ()) -> dict[str, list]:
    """``{setting apart from the model (and drop): runs}``.  A run joins each group of other models' runs that it
    :func:`joins`; a group left holding only runs that joined others (the baseline's own) is dropped."""
    groups: dict[str, list] = {}
    for r in runs:
        groups.setdefault(setting(r, drop_model=True, drop=drop), []).append(r)
    joined, models = set(), {label: {r.model for r in rs} for label, rs in groups.items()}
    for r in runs:
        mine = setting(r, drop_model=True, drop=drop)
        for label, rs in groups.items():
            if r.model not in models[label] and joins(r, mine, label):
                rs.append(r)
                joined.add(id(r))
    return {label: rs for label, rs in groups.items() if not all(id(r) in joined for r in rs)}


def pick_runs(runs, variants=None) -> dict[str, Run]:
    """One finished run with a checkpoint per variant: the longest trained, then the lowest seed.

    ``variants`` defaults to the plain models (runs without ablations, no ceiling run)."""
    runs = [r if isinstance(r, Run) else Run.load(r) for r in runs]
    chosen = {}

    def order(r):
        steps = r.value("steps")
        return (
            -(steps if isinstance(steps, (int, float)) else 0),
            r.seed if isinstance(r.seed, int) else 1 << 30,
            str(r.path),
        )

    for r in sorted(runs, key=order):
        if r.checkpoint is None or r.status != "ok":
            continue
        if (variants is None and r.plain) or (variants is not None and r.variant in variants):
            chosen.setdefault(r.variant, r)
    return chosen


def load_chosen(chosen: dict) -> dict:
    """``{name: model}`` in eval mode of ``{name: run or shipped model name}`` (:func:`disent.models.load_run`)."""
    from disent.models import load_run

    return {name: load_run(r.path if isinstance(r, Run) else r)[0].eval() for name, r in chosen.items()}


def load_models(runs, variants=None) -> dict:
    """``{variant: model}`` for :func:`pick_runs`; empty when ``disent.models`` is not available."""
    try:
        import disent.models  # noqa: F401
    except ImportError:
        return {}
    return load_chosen(pick_runs(runs, variants))
