"""README.md and docs/*.md say nothing that does not exist.

* Every relative Markdown link (and image) resolves to a file of the repository, and an
  ``#anchor`` on a Markdown page to one of its headings.
* Every ``nutribench <command> [<subcommand>]`` named in them (in fenced code, indented code
  and inline code) is a command of the typer app, and every ``--option`` given to it is in
  that command's ``--help``; every ``python benchmarks/NAME.py`` (the developer's benchmarks)
  is a file, and the options given to a command script are in its ``--help``.
* Nothing refers to files outside the repository (``../shared``), to the specification by
  section number (``SPEC 3``) or to issue numbers: a reader of the repository alone cannot
  follow them.

The site build (``mkdocs build --strict``, in CI) checks the links between docs pages too;
this test needs no mkdocs and covers the README as well.
"""

from __future__ import annotations

import functools
import re
import unicodedata
from pathlib import Path

import pytest
from typer.testing import CliRunner

from nutribench.cli import app
from tests.conftest import benchmark_script

ROOT = Path(__file__).resolve().parent.parent
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]

_FENCE = re.compile(r"^(\s*)(`{3,}|~{3,})")
_LINK = re.compile(r"!?\[(?:[^\]\[]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
_INLINE_CODE = re.compile(r"(`+)(.+?)\1", re.S)
_COMMAND = re.compile(r"(?<![\w./\[-])nutribench((?:[ \t]+[^\s`|;&#]+)*)")
_SCRIPT = re.compile(r"(?<![\w./\[-])python[ \t]+(benchmarks/[\w.]+)((?:[ \t]+[^\s`|;&#]+)*)")
_FORBIDDEN = {
    "a file outside the repository": re.compile(r"\.\./shared|REFERENCE\.md|SPEC\.md"),
    "an issue number": re.compile(r"\b[Ii]ssues?\s+#?\d+"),
    "the specification by section": re.compile(r"\bSPEC\b"),
}


def split_markdown(text: str) -> tuple[str, list[str]]:
    """(prose with code blocks blanked, the lines of fenced and indented code blocks)."""
    prose, code, fence = [], [], None
    lines = text.replace("\\\n", " ").split("\n")
    for line in lines:
        m = _FENCE.match(line)
        if fence is None and m:
            fence = m.group(2)[0] * len(m.group(2))
            prose.append("")
        elif fence is not None:
            if line.strip().startswith(fence) and not line.strip().strip(fence[0]):
                fence = None
            else:
                code.append(line)
            prose.append("")
        elif line.startswith("    ") and line.strip().startswith("nutribench "):
            code.append(line)  # an indented code block's command
            prose.append("")
        else:
            prose.append(line)
    return "\n".join(prose), code


def slug(heading: str) -> str:
    """The anchor of a heading, as Python-Markdown's toc (mkdocs) and GitHub make it."""
    text = re.sub(r"`([^`]*)`", r"\1", heading)
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", text)
    text = unicodedata.normalize("NFKD", text).encode("ascii", "ignore").decode("ascii")
    text = re.sub(r"[^\w\s-]", "", text).strip().lower()
    return re.sub(r"[-\s]+", "-", text)


@functools.cache
def anchors(page: Path) -> frozenset[str]:
    prose, _ = split_markdown(page.read_text(encoding="utf-8"))
    heads = re.findall(r"^#{1,6}\s+(.+?)\s*#*\s*$", prose, re.M)
    return frozenset(slug(h) for h in heads)


def broken_links(page: Path, text: str | None = None) -> list[str]:
    """Every relative link of ``page`` (or of ``text`` read as if it were that page) that
    does not resolve."""
    text = page.read_text(encoding="utf-8") if text is None else text
    prose, _ = split_markdown(text)
    prose = _INLINE_CODE.sub("", prose)
    bad = []
    for target in _LINK.findall(prose):
        if re.match(r"[a-z][a-z0-9+.-]*:", target, re.I):  # http:, https:, mailto:
            continue
        path, _, anchor = target.partition("#")
        dest = (page.parent / path).resolve() if path else page
        if not dest.exists():
            bad.append(f"{target}: no file {dest.relative_to(ROOT) if dest.is_relative_to(ROOT) else dest}")
        elif not dest.is_relative_to(ROOT):
            bad.append(f"{target}: outside the repository")
        elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
            bad.append(f"{target}: no heading #{anchor} in {dest.relative_to(ROOT)}")
    return bad


def commands(text: str) -> list[str]:
    """Every ``nutribench ...`` invocation named in code (fenced, indented or inline)."""
    prose, code = split_markdown(text)
    spans = [m.group(2).replace("\n", " ") for m in _INLINE_CODE.finditer(prose)]
    found = []
    for chunk in [*code, *spans]:
        for m in _COMMAND.finditer(chunk):
            if re.search(r"\b(from|import)\s+$", chunk[: m.start()]):
                continue  # Python: `from nutribench import ...`
            found.append(("nutribench" + m.group(1)).strip())
    return found


def script_commands(text: str) -> list[str]:
    """Every ``python benchmarks/NAME.py ...`` named in code (fenced, indented or inline)."""
    prose, code = split_markdown(text)
    chunks = [*code, *(m.group(2).replace("\n", " ") for m in _INLINE_CODE.finditer(prose))]
    return [f"python {m.group(1)}{m.group(2)}".strip() for chunk in chunks for m in _SCRIPT.finditer(chunk)]


@functools.cache
def script_help(name: str) -> str | None:
    """``benchmarks/NAME.py --help`` of a command script (a typer ``app``); None for another script."""
    if "typer.Typer(" not in (ROOT / "benchmarks" / f"{name}.py").read_text(encoding="utf-8"):
        return None
    return CliRunner().invoke(benchmark_script(name).app, ["--help"], terminal_width=200).output


def check_script(line: str) -> str | None:
    """None if ``line`` (``python benchmarks/NAME.py ...``) names a script there, with options it has."""
    where, *tokens = line.split()[1:]
    path = ROOT / where
    if path.suffix != ".py" or not path.is_file():
        return f"{line!r}: no script {where}"
    out = script_help(path.stem)
    known = set(re.findall(r"--[a-z][a-z0-9-]*", out or ""))
    for tok in tokens if out is not None else ():
        for opt in re.findall(r"(?:^|[\[(|/])(--[a-z][a-z0-9-]*)", tok):
            if opt not in known:
                return f"{line!r}: {where} has no option {opt}"
    return None


@functools.cache
def help_text(path: tuple[str, ...]) -> str | None:
    result = CliRunner().invoke(app, [*path, "--help"])
    return result.output if result.exit_code == 0 else None


def _subcommands(help_out: str) -> set[str]:
    section = help_out.partition("\nCommands:\n")[2]
    return set(re.findall(r"^  ([a-z][\w-]*)", section, re.M))


def check_command(line: str) -> str | None:
    """None if ``line`` (``nutribench ...``) names a real command with real options."""
    tokens = line.split()[1:]
    path: list[str] = []
    out = help_text(())
    while tokens and not tokens[0].startswith("-") and _subcommands(out):
        word = tokens[0].strip("[]()'\",.:")
        if word not in _subcommands(out):
            if re.fullmatch(r"[a-z][a-z-]*", word) and not path:
                return f"{line!r}: no command {word!r} (nutribench has {sorted(_subcommands(out))})"
            if re.fullmatch(r"[a-z][a-z-]*", word):
                return f"{line!r}: no command {word!r} under {' '.join(path)}"
            break  # a placeholder such as COMMAND or <cmd>: nothing to check
        path.append(word)
        tokens = tokens[1:]
        out = help_text(tuple(path))
        if out is None:
            return f"{line!r}: `nutribench {' '.join(path)} --help` failed"
    if not path:
        return None
    known = set(re.findall(r"--[a-z][a-z0-9-]*", out))
    for tok in tokens:
        for opt in re.findall(r"(?:^|[\[(|/])(--[a-z][a-z0-9-]*)", tok):
            if opt not in known:
                return f"{line!r}: `nutribench {' '.join(path)}` has no option {opt}"
    return None


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_links_resolve(page):
    assert broken_links(page) == []


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_commands_exist(page):
    named = commands(page.read_text(encoding="utf-8"))
    errors = [e for e in map(check_command, dict.fromkeys(named)) if e]
    assert errors == []


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_benchmark_scripts_exist(page):
    named = script_commands(page.read_text(encoding="utf-8"))
    errors = [e for e in map(check_script, dict.fromkeys(named)) if e]
    assert errors == []


def test_the_pages_name_commands():
    """The scan finds what it should (a guard against a regex that matches nothing)."""
    named = {" ".join(c.split()[:3]) for p in PAGES for c in commands(p.read_text(encoding="utf-8"))}
    assert {"nutribench run --preset", "nutribench report --all", "nutribench db import"} <= named


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_no_references_a_reader_cannot_follow(page):
    text = page.read_text(encoding="utf-8")
    hits = [f"{what}: {m.group(0)!r}" for what, rx in _FORBIDDEN.items() for m in rx.finditer(text)]
    assert hits == []


def test_the_checks_catch_planted_mistakes():
    page = ROOT / "docs" / "index.md"
    planted = "See [the engine](no-such-page.md), [a heading](getting-started.md#no-such-heading)."
    assert len(broken_links(page, planted)) == 2
    assert broken_links(page, "[ok](getting-started.md#a-tour) and [site](https://example.org/x.md)") == []
    assert check_command("nutribench run --preset smoke") is None
    assert check_command("nutribench db import part1.npz --db there.db") is None
    assert "no command 'frobnicate'" in check_command("nutribench frobnicate")
    assert "no command 'vacuum'" in check_command("nutribench db vacuum x.db")
    assert "no option --no-such-option" in check_command("nutribench report --fig 3 --no-such-option")
    text = "Run `nutribench runn --preset smoke`.\n\n```bash\nnutribench status --db x.db\n```\n"
    text += "```python\nfrom nutribench import SHIPPED_REGIMES\nimport nutribench  # registers\n```\n"
    assert commands(text) == ["nutribench status --db x.db", "nutribench runn --preset smoke"]
    assert check_script("python benchmarks/learn.py --algos mc --days 2000") is None
    assert "no option --no-such-option" in check_script("python benchmarks/engines.py --no-such-option")
    assert "no script benchmarks/nope.py" in check_script("python benchmarks/nope.py")
    assert script_commands("Run `python benchmarks/status.py --db x.db`.") == ["python benchmarks/status.py --db x.db"]
