"""The report as a Markdown document: sections that survive one another's failures, and what a build keeps of
the published report (sections, rows and subsections whose inputs it lacks, the provenance table)."""

from __future__ import annotations

import json
import re
import traceback
from pathlib import Path

from disent.runs import model_names, retyped_label


def pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def unoverlap(ax, labels, pad_pt: float = 1.0) -> None:
    """Move the point labels ``labels`` (``ax.annotate`` with ``textcoords="offset points"``) down, from the highest
    one, until no two texts overlap; each keeps its line to its point."""
    from matplotlib.text import Text

    fig = ax.figure
    renderer = fig.canvas.get_renderer()
    to_pt = 72 / fig.dpi

    def box(label):  # the text alone, not its line to the point
        label.update_positions(renderer)
        return Text.get_window_extent(label, renderer)

    placed = []
    for label in sorted(labels, key=lambda t: -box(t).y0):
        here = box(label)
        while hit := next((b for b in placed if here.overlaps(b)), None):
            x, y = label.xyann
            label.xyann = (x, y - (here.y1 - hit.y0) * to_pt - pad_pt)
            here = box(label)
        placed.append(here)


def load_json(path: Path):
    try:
        return json.loads(Path(path).read_text())
    except (OSError, ValueError):
        return None


def rel_path(path: Path, out: Path) -> str:
    try:
        return str(Path(path).resolve().relative_to(out.resolve()))
    except ValueError:
        return str(path)


class Report:
    """Markdown assembled section by section; each section survives the others' failures."""

    def __init__(self, out: Path, previous: str = "", only=None, measured=()):
        self.out = Path(out)
        self.only = set(only) if only else None  # section names (sec_NAME) to build; the others are kept
        self.fig = self.out / "figures"
        self.fig.mkdir(parents=True, exist_ok=True)
        self.lines: list[str] = []
        self.previous = published_sections(previous)  # what is published now, by section title
        self.revisions = published_revisions(previous)  # the git revision whose conf/ each section's labels name
        self.then: str | None = None  # that of the section being built
        # (setting apart from the model, model) of this build's runs, and (setting, None): a published row of one
        # of them is no longer kept (this build chose its rows)
        self.measured: set[tuple[str, str | None]] = set(measured)
        self.title = ""  # the section being built
        self.kept_rows = 0  # rows of the published section kept by rows_kept in the section being built

    def add(self, *lines: str) -> None:
        self.lines.extend(lines)

    def note(self, text: str) -> None:
        self.lines.append(f"{MISSING} {text}\n")

    def image(self, path: Path, alt: str) -> None:
        self.lines.append(f"![{alt}]({rel_path(path, self.out)})\n")

    def figure(self, fig, name: str, alt: str, rect=(0, 0, 1, 1)) -> None:
        """Lay out ``fig`` (its axes inside ``rect``, a share of the figure: room for a figure legend), save it as
        ``figures/<name>``, close it and show it here."""
        fig.tight_layout(rect=rect)
        path = self.fig / name
        fig.savefig(path, dpi=120)
        pyplot().close(fig)
        self.image(path, alt)

    def section(self, title: str, fn, *args) -> None:
        """``## title`` and what ``fn`` adds.  Where ``fn`` finds only missing inputs (or fails) but the
        published report has content for the section, that content is kept, marked as such."""
        self.add(f"## {title}\n")
        self.title, self.kept_rows, self.then = title, 0, self.revisions.get(section_name(fn))
        start = len(self.lines)
        old = self.previous.get(title, [])
        if self.only is not None and section_name(fn) not in self.only and old:
            self.lines += [f"{KEPT} as published before; not rebuilt in this build (`--sections`)\n"]
            self.lines += [line for line in old if not line.startswith(KEPT)]
            return
        try:
            fn(self, *args)
        except Exception as e:  # a broken section is reported, the rest of the report still builds
            self.note(f"this section failed: `{type(e).__name__}: {e}`")
            traceback.print_exc()
        if self.kept_rows:
            self.add(f"_{KEPT_ROW}: {KEPT_ROW_TEXT}_\n")
        new = self.lines[start:]
        if all(line.startswith(MISSING) for line in new) and any(not line.startswith((MISSING, KEPT)) for line in old):
            why = " ".join(line[len(MISSING) :].strip() for line in new)
            self.lines[start:] = [f"{KEPT} as published before; its inputs are missing in this build ({why})\n"] + [
                line for line in old if not line.startswith(KEPT)
            ]

    def rows_kept(
        self, head: str, rows: list[str], key: int | tuple[int, ...] = 1, unless: str | None = None
    ) -> list[str]:
        """``rows`` of a table with header line ``head``, then the rows of the published table under the same
        header in this section whose key cells (the first ``key``, or the cells numbered in ``key``) match none
        of ``rows`` (and that do not contain ``unless``): an earlier build measured them on runs this build does
        not have.  Those are marked :data:`KEPT_ROW` (a note under the section says why)."""
        picked = range(key) if isinstance(key, int) else key

        def key_of(line):
            cells = line.strip().strip("|").split("|")
            return tuple(retyped_cell(cells[i].replace(KEPT_ROW, "")) for i in picked if i < len(cells))

        have = {key_of(r) for r in rows}
        kept = []
        for block in self.previous.get(self.title, []):
            lines = block.rstrip("\n").split("\n")
            for line in lines[2:] if lines[0] == head else []:
                if not line.startswith("|") or (unless and unless in line):
                    continue
                cells = retyped_cells(line.split("|"), self.then)  # its labels as today names them
                if key_of("|".join(cells)) in have or self.names_measured(cells):
                    continue
                if KEPT_ROW not in cells[1]:
                    cells[1] = f"{cells[1].rstrip()} {KEPT_ROW} "
                kept.append("|".join(cells))
        self.kept_rows += len(kept)
        return [*rows, *kept]

    def names_measured(self, cells: list[str]) -> bool:
        """Whether a row's cells name the setting of one of this build's runs, for the row's model (a cell that is a
        model's name) or in a label that names the model itself."""
        model = found if (found := row_model(cells)) in model_names() else None  # not an ablation's row
        labels = [c.strip()[1:-1] for c in cells if len(c.strip()) > 2 and c.strip()[0] == c.strip()[-1] == "`"]
        return any((label, model) in self.measured or (label, None) in self.measured for label in labels)

    def subsections_kept(self, start: int) -> None:
        """Append the published ``###`` subsections of this section whose headings ``self.lines[start:]`` lack
        (an earlier build measured them on runs this build does not have), their headings marked :data:`KEPT_ROW`."""

        def heading(block, then=None, model=None):
            head = block.split("\n")[0].replace(KEPT_ROW, "").strip()
            if not head.startswith("### `"):
                return head
            return f"### {retyped_cell(head[4:], then, model)}".replace("`(defaults)`", "(defaults)")  # as written

        have = {heading(line) for line in self.lines[start:] if line.startswith("### ")}
        groups: list[list[str]] = []
        for block in self.previous.get(self.title, []):
            if block.startswith("### "):
                groups.append([block])
            elif groups and not block.startswith(f"_{KEPT_ROW}:"):
                groups[-1].append(block)
        for head, *body in groups:  # a heading names no model: dropped where it reads as a heading of today's
            if any(heading(head, self.then, m) in have for m in model_names()):
                continue
            if (published := heading(head, self.then)) not in have:
                self.add(f"{published} {KEPT_ROW}\n", *body)
                self.kept_rows += 1


def retyped_cell(cell: str, then: str | None = None, model: str | None = None) -> str:
    """A table cell or heading that names a setting (```+experiment=long train.max_steps=10000```), published
    against the ``conf/`` of git revision ``then``, read against today's (:func:`disent.runs.retyped_label`, for a
    run of ``model``): a row an earlier build published under a default since changed then matches the row this
    build writes for the same runs.  Any other cell, stripped."""
    text = cell.strip()
    inner = text[1:-1] if len(text) > 2 and text[0] == text[-1] == "`" else None
    if inner is None or not all("=" in w or w == "(defaults)" for w in inner.split()):
        return text
    return f"`{retyped_label(inner, then, model)}`"


def row_model(cells: list[str]) -> str | None:
    """The cell of a table row that names its model (``implicit``, ``explicit+no_bws``), None where none does."""
    return next((m for c in cells if (m := c.replace(KEPT_ROW, "").strip()).split("+")[0] in model_names()), None)


def retyped_cells(cells: list[str], then: str | None) -> list[str]:
    """A published table row's cells, each that names a setting read by :func:`retyped_cell` for the row's model
    (a cell naming one, ``implicit`` or ``explicit+no_bws``; none: unknown); the other cells as they were."""
    model = (row_model(cells) or "").split("+")[0] or None
    return [
        f" {retyped_cell(c.replace(KEPT_ROW, ''), then, model)}{' ' + KEPT_ROW if KEPT_ROW in c else ''} "
        if c.strip().startswith("`")
        else c
        for c in cells
    ]


MISSING, KEPT = "> **Missing:**", "> **Kept:**"


KEPT_ROW = "‡"
KEPT_ROW_TEXT = (
    "as an earlier build published it; its runs are not among this build's inputs (their folders are gone and "
    "they left no record in `reports/runs/`)"
)
PROVENANCE = ("sections", "built", "from", "regenerate")  # the header's table: one row per build still shown


def provenance_row(sections: list[str], built: str, source: str, command: str) -> str:
    """One build's row of the header's table (``sections``: what it built that no later build rebuilt)."""
    return f"| {', '.join(sections)} | {built} | {source} | `{command}` |"


def kept_provenance(previous: str, rebuilt: list[str]) -> list[str]:
    """The rows of ``previous``'s provenance table that still describe a section after a ``--sections rebuilt``
    build: each row less the sections rebuilt now, its command rewritten to build only what it has left; a row
    goes once none is left."""
    kept = []
    for line in previous.split("\n## ")[0].splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split(" | ")]
        if not line.startswith("| ") or len(cells) != len(PROVENANCE) or cells[0] == PROVENANCE[0]:
            continue
        left = [s for s in cells[0].split(", ") if s not in rebuilt]
        if left:
            command = re.sub(r" --compute| --sections [\w ]+", "", cells[3].strip("`"))
            kept.append(provenance_row(left, cells[1], cells[2], f"{command} --sections {' '.join(left)}"))
    return kept


def published_revisions(markdown: str) -> dict[str, str]:
    """``{section name: git revision}`` of the header's provenance table in a published report: the build whose
    ``conf/`` the section's setting labels name (a kept row or section is read again at each build that writes its
    section)."""
    out = {}
    for line in markdown.split("\n## ")[0].splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split(" | ")]
        if line.startswith("| ") and len(cells) == len(PROVENANCE) and (m := re.match(r"`([0-9a-f]{7,40})`", cells[1])):
            out.update({name: m.group(1) for name in cells[0].split(", ")})
    return out


def heading_anchor(title: str, seen: dict[str, int]) -> str:
    """The anchor GitHub gives a Markdown heading: lower case, each character that is not a letter, digit,
    ``_``, ``-`` or space dropped, spaces made ``-``; the n-th repeat of an anchor in a document gets ``-n``
    (``seen``: the anchors so far, updated)."""
    slug = re.sub(r"[^\w\- ]", "", title.strip().lower()).replace(" ", "-")
    n = seen.get(slug, 0)
    seen[slug] = n + 1
    return slug if n == 0 else f"{slug}-{n}"


def contents(markdown: str, open_sections=("The paper's claims, measured",)) -> list[str]:
    """The report's contents: each section (``## ``) linked to its heading, and under the sections named in
    ``open_sections`` their subsections (``### ``)."""
    seen: dict[str, int] = {}
    lines, section, fenced = ["**Contents**\n"], None, False
    for line in markdown.splitlines():
        fenced ^= line.startswith("```")
        if fenced or not (m := re.match(r"(#{1,6}) (.+)", line)):
            continue
        level, title = len(m.group(1)), m.group(2).strip()
        link = f"[{title}](#{heading_anchor(title, seen)})"
        if level == 2:
            section = title
            lines.append(f"- {link}")
        elif level == 3 and section in open_sections:
            lines.append(f"  - {link}")
    return ["\n".join(lines) + "\n"] if len(lines) > 1 else []


def section_name(fn) -> str:
    """A section's name for ``--sections``: its function's, less ``sec_`` (``sec_claims``: ``claims``)."""
    return fn.__name__.removeprefix("sec_")


def published_sections(markdown: str) -> dict[str, list[str]]:
    """``{title: lines}`` of a report written by :class:`Report` (each ``## title`` up to the next)."""
    sections, title = {}, None
    for block in markdown.split("\n## ")[1:]:
        head, _, body = block.partition("\n")
        title = head.strip()
        sections[title] = [b + "\n" for b in body.strip("\n").split("\n\n") if b.strip()]
    return sections
