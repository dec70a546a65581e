"""One page to look at: ``index.html`` beside a report's files, with its figures (the PNGs,
by relative link) and its tables (the formatted tables as HTML tables) on one static page.

No server, no network, no external CSS or JavaScript: the page opens from the folder (or a
copy of it) in any browser. A small inline script marks, once the page has loaded, how many
of its images did load (``<body data-loaded="N" data-images="M">``), so that a headless
browser can check the page (tests/test_report_html.py).
"""

from __future__ import annotations

import html
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd

INDEX = "index.html"

_STYLE = """
body { font-family: sans-serif; margin: 1.5em auto; max-width: 1200px; padding: 0 1em; color: #222; }
nav a { margin-right: 0.8em; }
figure { margin: 1.5em 0; }
figure img { max-width: 100%; height: auto; border: 1px solid #ddd; }
figcaption, .notes, .caption { font-size: 0.9em; color: #555; }
table { border-collapse: collapse; font-size: 0.85em; margin: 0.5em 0 1.5em; }
th, td { border: 1px solid #ccc; padding: 0.2em 0.5em; text-align: left; vertical-align: top; }
th { background: #f2f2f2; }
tr:nth-child(even) td { background: #fafafa; }
"""

_SCRIPT = """
window.addEventListener("load", function () {
  var imgs = Array.prototype.slice.call(document.images);
  var ok = imgs.filter(function (i) { return i.complete && i.naturalWidth > 0; });
  document.body.dataset.images = String(imgs.length);
  document.body.dataset.loaded = String(ok.length);
});
"""


@dataclass
class PageItem:
    """One figure (``png``: its file, relative to the page) or one table (``table``) of the page."""

    stem: str
    title: str
    png: str | None = None
    table: pd.DataFrame | None = None
    notes: list[str] = field(default_factory=list)
    files: list[str] = field(default_factory=list)
    caption: str = ""  # a table's whole caption, a paragraph under its short heading


def table_html(frame: pd.DataFrame) -> str:
    """``frame`` as an HTML table, every cell escaped."""
    head = "".join(f"<th>{html.escape(str(c))}</th>" for c in frame.columns)
    body = "\n".join(
        "<tr>" + "".join(f"<td>{html.escape(str(v))}</td>" for v in row) + "</tr>"
        for row in frame.itertuples(index=False)
    )
    return f"<table>\n<thead><tr>{head}</tr></thead>\n<tbody>\n{body}\n</tbody>\n</table>"


def _links(files: Sequence[str]) -> str:
    return " · ".join(
        f'<a href="{html.escape(f, quote=True)}">{html.escape(Path(f).suffix.lstrip(".") or f)}</a>' for f in files
    )


def page_html(items: Sequence[PageItem], title: str = "nutribench report", subtitle: str = "") -> str:
    """The page: a contents line, then each figure and each table with its files linked."""
    nav = " ".join(f'<a href="#{html.escape(i.stem, quote=True)}">{html.escape(i.stem)}</a>' for i in items)
    parts = []
    for i in items:
        sid = html.escape(i.stem, quote=True)
        notes = "".join(f'<p class="notes">note: {html.escape(n)}</p>' for n in i.notes)
        caption = f'<p class="caption">{html.escape(i.caption)}</p>\n' if i.caption else ""
        files = f'<p class="notes">files: {_links(i.files)}</p>' if i.files else ""
        if i.png is not None:
            src = html.escape(i.png, quote=True)
            shown = f'<figure><a href="{src}"><img src="{src}" alt="{sid}"></a><figcaption>{html.escape(i.stem)}</figcaption></figure>'
        else:
            shown = caption + (table_html(i.table) if i.table is not None else "")
        parts.append(f'<section id="{sid}">\n<h2>{html.escape(i.title)}</h2>\n{shown}\n{notes}{files}\n</section>')
    sub = f"<p>{html.escape(subtitle)}</p>" if subtitle else ""
    return (
        f'<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n<title>{html.escape(title)}</title>\n'
        f"<style>{_STYLE}</style>\n<script>{_SCRIPT}</script>\n</head>\n<body>\n<h1>{html.escape(title)}</h1>\n{sub}\n"
        f"<nav>{nav}</nav>\n" + "\n".join(parts) + "\n</body>\n</html>\n"
    )


def write_index(
    items: Sequence[PageItem], out_dir: str | Path, title: str = "nutribench report", subtitle: str = ""
) -> Path:
    """Write ``<out_dir>/index.html`` with ``items`` (their files relative to ``out_dir``)."""
    from nutribench.report.output import write_atomically

    page = page_html(items, title, subtitle)
    return write_atomically(Path(out_dir) / INDEX, lambda tmp: tmp.write_text(page, encoding="utf-8"))


def page_figure(number: int, res: Any, written: Sequence[Path]) -> PageItem:
    """Figure ``number`` on index.html: its PNG, the first line of its title, its notes."""
    heading = (res.figure.get_suptitle().splitlines() or [""])[0]
    title = f"Figure {number}" + (f": {heading}" if heading else "")
    return PageItem(written[0].stem, title, png=written[0].name, notes=list(res.notes), files=[p.name for p in written])


#: Longest table heading taken from a caption's head (``Leaderboard: every agent ranked ...``).
HEADING_CHARS = 40


def table_heading(stem: str, title: str) -> str:
    """A table's short heading: its caption's head before the first ``: `` (``Leaderboard``,
    ``Table 1``, ``Results``) when short, else the file stem (``table_results``) made readable."""
    head = title.split(": ", 1)[0].strip()
    if head and head != title.strip() and len(head) <= HEADING_CHARS and "\n" not in head:
        return head
    return stem.replace("_", " ").capitalize()


def page_table(stem: str, res: Any, written: Sequence[Path]) -> PageItem:
    """A table on index.html: a short heading (:func:`table_heading`), its whole caption as a
    paragraph under it, and its formatted frame as an HTML table."""
    return PageItem(
        stem, table_heading(stem, res.title), table=res.formatted, files=[p.name for p in written], caption=res.title
    )
