"""``nutribench report --all`` writes ``index.html``, one static page with
the report's figures and tables; a headless Chromium (Debian's ``chromium`` package, installed
by ``.ci/run``; nothing downloaded at run time) renders it and every figure loads.

The page's own inline script sets ``<body data-images="M" data-loaded="N">`` on load (N: the
images complete with ``naturalWidth > 0``); the DOM Chromium dumps after loading is read back.
Without Chromium the test fails in CI (``CI`` set) and is skipped, with the reason, elsewhere.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest
from test_report_cli import REF_EPISODES, invoke, make_db

from nutribench.report.build import FIGURES, TABLES
from nutribench.report.html import PageItem, write_index

BROWSERS = ("chromium", "chromium-browser", "google-chrome")


def _browser() -> str:
    for name in BROWSERS:
        found = shutil.which(name)
        if found:
            return found
    why = f"no headless browser ({', '.join(BROWSERS)}) on PATH: apt-get install chromium (.ci/run does)"
    if os.environ.get("CI"):
        pytest.fail(why)
    pytest.skip(why)


def _chromium(page: Path, tmp: Path, *extra: str) -> subprocess.CompletedProcess:
    args = [
        _browser(),
        "--headless",
        "--disable-gpu",
        "--no-sandbox",
        "--no-first-run",
        "--disable-extensions",
        f"--user-data-dir={tmp / 'profile'}",
        "--virtual-time-budget=10000",
        *extra,
        page.resolve().as_uri(),
    ]
    return subprocess.run(args, capture_output=True, text=True, timeout=120, check=False)


def _loaded(page: Path, tmp: Path) -> tuple[int, int, str]:
    """(images, images loaded) as the page's script counted them, and the dumped DOM."""
    res = _chromium(page, tmp, "--dump-dom")
    dom = res.stdout
    body = re.search(r"<body[^>]*>", dom)
    assert body, f"no <body> in chromium's DOM (exit {res.returncode}): {res.stderr[-2000:]}"
    images = re.search(r'data-images="(\d+)"', body.group(0))
    loaded = re.search(r'data-loaded="(\d+)"', body.group(0))
    assert images and loaded, f"the page's onload script did not run: {body.group(0)}"
    return int(images.group(1)), int(loaded.group(1)), dom


@pytest.mark.slow
def test_report_all_page_renders_with_every_figure_loaded(tmp_path: Path):
    db = make_db(tmp_path / "r.db")
    out = tmp_path / "reports"
    result = invoke("--all", "--db", str(db), "--out", str(out), *REF_EPISODES)
    assert result.exit_code == 0, result.output
    page = out / "index.html"
    assert page.is_file() and "index.html" in result.stdout
    text = page.read_text()
    # static: no server, no network, no external CSS or JavaScript; links are relative
    assert not re.search(r"""(src|href)=["'](https?:|//|/)""", text) and "<link" not in text
    pngs = sorted(p.name for p in out.glob("*.png"))
    assert len(pngs) == len(FIGURES)
    assert sorted(re.findall(r'<img src="([^"]+)"', text)) == pngs
    # every table written, as an HTML table
    for stem in TABLES.values():
        if (out / f"{stem}.md").exists():
            assert f'<section id="{stem}">' in text
    assert text.count("<table>") == len(list(out.glob("*.md")))
    images, loaded, dom = _loaded(page, tmp_path)
    assert images == text.count("<img ") == len(FIGURES)
    assert loaded == images, f"{loaded} of {images} figures loaded"
    assert dom.count("<td>") > 50  # the tables are in the rendered page
    shot = tmp_path / "page.png"
    _chromium(page, tmp_path, f"--screenshot={shot}", "--window-size=1280,2400", "--hide-scrollbars")
    assert shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    if os.environ.get("NUTRIBENCH_KEEP_SCREENSHOT"):  # to look at it: the page as Chromium drew it
        shutil.copy(shot, os.environ["NUTRIBENCH_KEEP_SCREENSHOT"])


def test_the_check_sees_a_figure_that_does_not_load(tmp_path: Path):
    """The counter is not a formality: a page whose second PNG is missing counts one of two."""
    import pandas as pd
    from matplotlib.figure import Figure

    fig = Figure(figsize=(2, 1))
    fig.savefig(tmp_path / "a.png")
    items = [
        PageItem("a", "Figure A", png="a.png"),
        PageItem("b", "Figure B", png="missing.png"),
        PageItem("t", "Table <T> & co", table=pd.DataFrame({"x<": ["1 & 2"]})),
    ]
    page = write_index(items, tmp_path)
    assert "Table &lt;T&gt; &amp; co" in page.read_text() and "<td>1 &amp; 2</td>" in page.read_text()
    images, loaded, _ = _loaded(page, tmp_path)
    assert (images, loaded) == (2, 1)
