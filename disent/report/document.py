"""The report's pages as Markdown documents: sections that survive one another's failures, figures saved so that a
rebuild gives the same bytes, links relative to each page."""

from __future__ import annotations

import os
import re
import traceback
from pathlib import Path

from disent.images import save_figure


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


class Report:
    """One page of the report (``reports/README.md`` or an appendix page), assembled section by section; each
    section survives the others' failures."""

    def __init__(self, out: Path, page: str = "README.md"):
        self.out = Path(out)
        self.page = self.out / page
        self.fig = self.out / "figures"
        self.fig.mkdir(parents=True, exist_ok=True)
        self.lines: list[str] = []
        self.failed: list[str] = []  # the sections that raised (--check fails on any)

    def add(self, *lines: str) -> None:
        self.lines.extend(lines)

    def note(self, text: str) -> None:
        self.lines.append(f"{MISSING} {text}\n")

    def link(self, path: Path) -> str:
        """``path`` as a link from this page (figures and other pages)."""
        return os.path.relpath(Path(path).resolve(), self.page.parent.resolve())

    def image(self, path: Path, alt: str) -> None:
        self.lines.append(f"![{alt}]({self.link(path)})\n")

    def figure(self, fig, name: str, alt: str, rect=(0, 0, 1, 1)) -> None:
        """Lay out ``fig`` (its axes inside ``rect``, a share of the figure: room for a figure legend), save it as
        ``figures/<name>``, close it and show it here."""
        fig.tight_layout(rect=rect)
        path = self.fig / name
        save_figure(fig, path, dpi=120)
        self.image(path, alt)

    def section(self, title: str, fn, *args, level: int = 2) -> None:
        """``## title`` (``level`` hashes) and what ``fn`` adds; a section that raises is noted, the page goes on."""
        self.add(f"{'#' * level} {title}\n")
        try:
            fn(self, *args)
        except Exception as e:  # a broken section is reported, the rest of the report still builds
            self.note(f"this section failed: `{type(e).__name__}: {e}`")
            self.failed.append(title)
            traceback.print_exc()

    def write(self, contents_list: bool = False) -> Path:
        """Write the page (with a contents list under its first heading where ``contents_list``)."""
        if contents_list:  # above the first section
            at = next((i for i, line in enumerate(self.lines) if line.startswith("## ")), len(self.lines))
            self.lines[at:at] = contents("\n".join(self.lines))
        self.page.parent.mkdir(parents=True, exist_ok=True)
        self.page.write_text("\n".join(self.lines) + "\n")
        return self.page


MISSING = "> **Missing:**"


def heading_anchor(title: str, seen: dict[str, int]) -> str:
    """The anchor GitHub gives a Markdown heading: lower case, each character that is not a letter, digit,
    ``_``, ``-`` or space dropped, spaces made ``-``; the n-th repeat of an anchor in a document gets ``-n``
    (``seen``: the anchors so far, updated)."""
    slug = re.sub(r"[^\w\- ]", "", title.strip().lower()).replace(" ", "-")
    n = seen.get(slug, 0)
    seen[slug] = n + 1
    return slug if n == 0 else f"{slug}-{n}"


def contents(markdown: str, open_sections=()) -> list[str]:
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
