"""What every section shares: seed spreads and verdicts, table cells, which runs a table reads."""

from __future__ import annotations

from pathlib import Path

from disent.eval import ablation as _ablation
from disent.runs import Run, composed_config, defining_overrides, setting
from disent.storage import machine_text

MODELS = ("baseline", "explicit", "implicit")
INFER_SPEED_KEY = "infer_images_per_s"  # eval.json


RUNG = ("model=", "+experiment=", "experiment=")  # a run of the budget ladder sets only these
MIN_SEEDS = 3  # a verdict needs at least this many seeds per arm
EDIT_WORKS = 0.5  # an edit works where at least this share of the edited faces reads as having the attribute


def seed_spread(runs: list[Run], key: str) -> dict | None:
    """Mean, std and count over the seeds of ``runs`` of one metric, a seed's repeated runs averaged
    (:func:`disent.eval.ablation.seed_mean_std`)."""
    return _ablation.seed_mean_std(runs, key)


def table_head(*columns: str) -> tuple[str, str]:
    """A Markdown table's header line and its separator, one column each."""
    return "| " + " | ".join(columns) + " |", "|" + "---|" * len(columns)


def fmt_value(value, fmt: str) -> str:
    return "–" if value is None else f"{value:{fmt}}"


def spread_text(st, fmt=".2f", count: bool = True) -> str:
    """``mean ± std (n=N)`` of a :func:`seed_spread` (``n=N; R runs`` where some seed ran more than once); without
    the count where the table has a seeds column."""
    if st is None:
        return "–"
    n = f" (n={seeds_text(st)})" if count else ""
    return _ablation.mean_std_text(st["mean"], None if st["n"] == 1 else st["std"], fmt) + n


def seeds_text(st) -> str:
    """The seed count of a :func:`seed_spread`, with the runs behind it where a seed ran more than once."""
    runs = st.get("runs", st["n"])
    return f"{st['n']}; {runs} runs" if runs > st["n"] else str(st["n"])


def seeds_cell(runs: list[Run]) -> str:
    """A table's seeds cell: how many seeds ``runs`` hold, and how many runs where some seed ran more than once."""
    seeds = len({_ablation.seed_key(r, i) for i, r in enumerate(runs)})
    return f"{seeds} ({len(runs)} runs)" if len(runs) > seeds else str(seeds)


def on_the_ladder(run: Run) -> bool:
    """A plain run of a budget rung (``smoke``, the defaults, ``long``): no override beyond model and experiment."""
    return all(o.startswith(RUNG) for o in defining_overrides(run))


def ladder_runs(runs: list[Run]) -> list[Run]:
    """The finished plain runs of the budget ladder (no ablation, no override beyond model and experiment)."""
    return [r for r in runs if r.status == "ok" and r.eval and not r.ablations and on_the_ladder(r)]


def machines(runs: list[Run]) -> str:
    """The machines ``runs`` trained on (their ``machine.json``), for a caption."""
    seen = sorted({machine_text(r.machine) for r in runs if r.machine})
    older = sum(1 for r in runs if not r.machine)
    text = "; ".join(seen) if seen else "not recorded"
    return text + (f" ({older} run(s) from before machines were recorded)" if seen and older else "")


def verdict(a, b, better: str) -> str:
    """Whether arm ``a`` beats arm ``b`` (``better``: "lower" or "higher"; each a :func:`seed_spread`): confirmed
    or refuted where the difference exceeds both arms' seed spread, else not resolved; not testable with fewer
    than ``MIN_SEEDS`` seeds in an arm."""
    if a is None or b is None:
        return "not testable (no runs)"
    if min(a["n"], b["n"]) < MIN_SEEDS:
        return f"not testable ({min(a['n'], b['n'])} seed(s); {MIN_SEEDS} needed)"
    diff = (b["mean"] - a["mean"]) if better == "lower" else (a["mean"] - b["mean"])
    if abs(diff) <= max(a["std"], b["std"]):
        return "not resolved (difference within the seed spread)"
    return "**confirmed**" if diff > 0 else "**refuted**"


def is_recipe_run(run: Run) -> bool:
    """A run of the training recipe's leave-one-out (ablations/recipe.sh): a folder under a ``recipe/`` folder.
    Each changes a setting without an ``+ablation``, so it belongs in the recipe table, not among a model's seeds."""
    return run.recipe


def by_setting_and_model(runs) -> dict:
    """``{(setting apart from the model, model): runs}`` (:func:`disent.runs.setting`), in the order the runs come."""
    groups: dict = {}
    for r in runs:
        groups.setdefault((setting(r, drop_model=True), r.model), []).append(r)
    return groups


LADDER_COLUMNS = tuple((rung, m) for rung in ("(defaults)", "+experiment=long") for m in ("explicit", "implicit"))


class Glance:
    """The verdicts the claims' tables give at the budget ladder's rungs, gathered as the tables are built, for one
    table at the head of the claims section: a row per reading of a claim, a column per rung and model."""

    def __init__(self):
        self.cells: dict = {}  # (claim, reading) -> {(rung, model): verdict}
        self.gates: dict = {}  # (rung, model) -> why a claim's verdicts there are not read (claim 4's budget gate)

    @staticmethod
    def column(where: str, model: str) -> tuple[str, str] | None:
        """The ladder column of a table row's setting (``model=`` tokens dropped), None for any other setting."""
        rest = " ".join(t for t in where.split() if not t.startswith("model=")) or "(defaults)"
        return (rest, model) if (rest, model) in LADDER_COLUMNS else None

    def put(self, claim: str, reading: str, where: str, model: str, text: str) -> None:
        if column := self.column(where, model):
            self.cells.setdefault((claim, reading), {})[column] = text

    def lines(self) -> list[str]:
        """The table (–: the reading is not measured at that rung), a sentence naming claim 4's budget gates and one
        naming the readings no rung can test yet (left out of the table)."""
        if not self.cells:
            return []
        head = table_head("claim", "reading", *(f"{m}, `{rung}`" for rung, m in LADDER_COLUMNS))
        rows, idle = [], []
        for (claim, reading), got in self.cells.items():
            if all(v.startswith("not testable") for v in got.values()):
                idle.append(f"{claim}: {reading}")
                continue
            rows.append(
                f"| {claim} | {reading} | " + " | ".join(short_verdict(got.get(c, "–")) for c in LADDER_COLUMNS) + " |"
            )
        untested = f"Not testable at either rung, so not listed: {'; '.join(idle)}.\n"
        gates = "; ".join(f"`{rung}` {model}: {why}" for (rung, model), why in self.gates.items())
        gated = (
            "Claim 4's cells give the ablation's *difference*; its verdicts are read only where the full model meets "
            f"the default-run targets, and are not testable here: {gates}.\n"
        )
        return [*head, *rows, "", *([gated] if gates else []), *([untested] if idle else [])]


def verdict_word(text: str) -> str:
    """A verdict less its reason (``not testable (2 seed(s); 3 needed)`` -> ``not testable``)."""
    return text.split(" (")[0]


def short_verdict(text: str) -> str:
    """A verdict cell for the glance: *not resolved* without its standing reason (the tables say it)."""
    return "not resolved" if text.startswith("not resolved (") else text


def shipped_run(name: str) -> Run:
    """The shipped weights ``name`` as a run (their manifest's config; the folder they trained in): at the long
    rung where they ran its steps."""
    from disent.models.shipped import manifest

    entry = manifest()[name]
    long_steps = composed_config(("+experiment=long",))["train"]["max_steps"]
    rung = ["+experiment=long"] if entry["cfg"].get("train", {}).get("max_steps") == long_steps else []
    return Run(path=Path(entry.get("run") or name), cfg=entry["cfg"], overrides=rung)
