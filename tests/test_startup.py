"""Start-up: what a command imports before it does anything.

``nutribench status`` on an up-to-date database checks the schema revision with plain SQL and
reads the revision chain from the migration files, so it imports no alembic (a fifth of its
start-up); alembic comes in only to upgrade. Nor does it import gymnasium, numpy or torch:
``import nutribench`` registers the environment's ids as gymnasium is imported, not by
importing it.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from alembic.script import ScriptDirectory

from nutribench.cli import COMMANDS, build_app, get_app
from nutribench.store.schema import alembic_config, head_revision, open_store, revision_chain

REPO = Path(__file__).resolve().parents[1]


def run_script(script: str, *args: str, cwd: Path | None = None, timeout: int = 120) -> subprocess.CompletedProcess:
    """``script`` run by a fresh interpreter (``python -c script args...``): a process of its own,
    so what it imports is what the code under test imports; its output captured as text."""
    return subprocess.run(
        [sys.executable, "-c", script, *args], cwd=cwd, capture_output=True, text=True, timeout=timeout
    )


def _alembic_chain() -> list[str]:
    script = ScriptDirectory.from_config(alembic_config())
    return [s.revision for s in reversed(list(script.walk_revisions()))]


def test_the_revision_chain_read_from_the_files_is_alembics() -> None:
    assert revision_chain() == _alembic_chain()
    assert head_revision() == ScriptDirectory.from_config(alembic_config()).get_current_head()


def test_a_new_revision_file_is_the_new_head(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    folder = tmp_path / "migrations"
    shutil.copytree(REPO / "migrations", folder, ignore=shutil.ignore_patterns("__pycache__"))
    head = revision_chain()[-1]
    (folder / "versions" / "9999_next.py").write_text(
        f'"""A later revision."""\n\nrevision = "nbtest9"\ndown_revision = "{head}"\n'
        "branch_labels = None\ndepends_on = None\n\n\ndef upgrade():\n    pass\n\n\ndef downgrade():\n    pass\n"
    )
    monkeypatch.setenv("NUTRIBENCH_MIGRATIONS", str(folder))
    assert revision_chain() == [*_alembic_chain()[:-1], "nbtest9"] == _alembic_chain()
    assert head_revision() == "nbtest9"


_STATUS = """
import sys
from nutribench.cli import main
sys.argv = ["nutribench", "status", "--db", sys.argv[1], "--json"]
try:
    main()
finally:
    print("ALEMBIC" if any(n == "alembic" or n.startswith("alembic.") for n in sys.modules) else "NO-ALEMBIC")
    print(" ".join(sorted(n for n in sys.modules if n.startswith("nutribench.cli."))))
    heavy = ("gymnasium", "numpy", "torch", "pandas", "nutribench.env")
    print(" ".join(n for n in heavy if n in sys.modules) or "-")
"""


def test_status_on_an_up_to_date_database_imports_no_alembic_nor_other_commands(tmp_path: Path) -> None:
    db = tmp_path / "nb.db"
    open_store(db, writer=True).dispose()
    result = run_script(_STATUS, str(db), cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    *report, verdict, commands, heavy = result.stdout.strip().splitlines()
    assert json.loads("\n".join(report))["totals"]["jobs"] == 0
    assert verdict == "NO-ALEMBIC"
    assert heavy == "-"  # no gymnasium, numpy, torch, pandas nor the environment
    # the one command's module and what it imports, not the other commands'
    assert commands.split() == ["nutribench.cli.common", "nutribench.cli.run"]


_REGISTERED = """
import sys
if sys.argv[1] == "gymnasium-first":
    import gymnasium
import nutribench
print("gymnasium" in sys.modules, "numpy" in sys.modules)
import gymnasium
ids = {i for i in gymnasium.registry if i.startswith("nutribench/")}
print(ids == {nutribench.ENV_ID, *(f"nutribench/NutriRL-{r}-v0" for r in nutribench.SHIPPED_REGIMES)})
gymnasium.make(nutribench.ENV_ID, regime="run3").reset(seed=0)
"""


@pytest.mark.parametrize("first", ["nutribench-first", "gymnasium-first"])
def test_import_nutribench_registers_the_ids_without_importing_gymnasium(first: str) -> None:
    """``import nutribench`` imports neither gymnasium nor numpy; the ids are registered once
    gymnasium is imported, whichever of the two comes first."""
    result = run_script(_REGISTERED, first)
    assert result.returncode == 0, result.stderr
    imported, registered = result.stdout.strip().splitlines()
    assert imported == ("True True" if first == "gymnasium-first" else "False False")
    assert registered == "True"


def test_an_older_database_still_upgrades(tmp_path: Path) -> None:
    """The other side: a writer opening an older schema imports alembic and upgrades it."""
    from nutribench.store.engine import make_engine
    from nutribench.store.schema import upgrade_connection

    db = tmp_path / "old.db"
    engine = make_engine(f"sqlite:///{db}", writer=True)
    with engine.begin() as conn:
        upgrade_connection(conn, revision_chain()[0])
    engine.dispose()
    store = open_store(db, writer=True)
    try:
        assert (store.upgraded_from, store.revision) == (revision_chain()[0], revision_chain()[-1])
    finally:
        store.dispose()


@pytest.mark.parametrize("name", [name for name, _ in COMMANDS])
def test_one_command_app_says_what_the_whole_app_says(name: str) -> None:
    """``nutribench NAME ...`` builds only NAME's command (:func:`build_app` with ``only``); its
    help, and its subcommands' list, are the whole app's."""
    from typer.testing import CliRunner

    runner = CliRunner()
    whole = runner.invoke(get_app(), [name, "--help"], prog_name="nutribench", terminal_width=100)
    alone = runner.invoke(build_app(only=name), [name, "--help"], prog_name="nutribench", terminal_width=100)
    assert whole.exit_code == alone.exit_code == 0, (whole.output, alone.output)
    assert alone.output == whole.output


def test_the_whole_app_lists_every_command() -> None:
    import typer

    app = get_app()
    listed = [c.name for c in app.registered_commands] + [g.name for g in app.registered_groups]
    assert sorted(listed) == sorted(name for name, _ in COMMANDS)
    assert isinstance(build_app(only="status"), typer.Typer)
    assert [c.name for c in build_app(only="status").registered_commands] == ["status"]


_CHECK_AGENTS = """
import sys
import nutribench.agents.registry as registry
from nutribench.agents.config import list_agent_configs, load_agent_config
from nutribench.engine import supports
from nutribench.scheduler.grid import resolve_grid
from nutribench.scheduler.settings import GridSettings
names = list_agent_configs()
for name in names:
    cfg = load_agent_config(name)
    entry = registry.algorithm(cfg)
    registry.batch_limit(cfg, 50), supports(cfg, 50), entry.config_model(), entry.display
grid = resolve_grid(preset="smoke", regimes=["run0"], algos=names, seeds=None, episodes=2, eval_episodes=1)
GridSettings.of(grid, sys.argv[1]).check()
GridSettings.of(grid, sys.argv[1], engine="batched", device="cpu").check()
print(len(names), " ".join(n for n in ("torch", "stable_baselines3") if n in sys.modules) or "-")
"""


def test_checking_every_shipped_agent_config_imports_no_torch(tmp_path: Path) -> None:
    """What ``nutribench run`` checks before its first line (every agent file read, its
    registry entry and batch limits asked, the grid's settings checked on both engines)
    imports neither torch nor Stable-Baselines3: a built-in's module keeps its SB3 class
    elsewhere, imported when a model is built."""
    result = run_script(_CHECK_AGENTS, str(tmp_path / "nb.db"), cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    count, heavy = result.stdout.strip().split(" ", 1)
    assert int(count) >= 5 and heavy == "-"
    assert not (tmp_path / "nb.db").exists()  # checked, nothing created


_FIRST_LINE = """
import sys

class FirstWrite:
    '''stderr, noting whether torch was imported when the first line was written'''
    def __init__(self, stream):
        self.stream, self.first = stream, None
    def write(self, text):
        if self.first is None and text.strip():
            self.first = (text.strip().splitlines()[0], "torch" in sys.modules)
        return self.stream.write(text)
    def __getattr__(self, name):
        return getattr(self.stream, name)

sys.stderr = seen = FirstWrite(sys.stderr)
from nutribench.cli import main
sys.argv = ["nutribench", *sys.argv[1:]]
try:
    main()
finally:
    print(seen.first[1], "torch" in sys.modules, seen.first[0], file=sys.__stdout__)
"""


def test_run_says_what_it_starts_before_torch_is_imported(tmp_path: Path) -> None:
    """``nutribench run``'s first line (what it starts) is written before torch is imported;
    the job then trains (torch comes in) and the run ends well."""
    args = ["run", "--preset", "smoke", "--regimes", "run0", "--algos", "mc", "--days", "2", "--eval-episodes", "1"]
    result = run_script(_FIRST_LINE, *args, "--db", str(tmp_path / "nb.db"), cwd=tmp_path, timeout=600)
    assert result.returncode == 0, result.stderr
    torch_at_first_line, torch_at_end, first = result.stdout.split(" ", 2)
    assert first.startswith("nutribench run: 1 job (1 regime x 1 agent mc"), first
    assert (torch_at_first_line, torch_at_end) == ("False", "True")


_TUNE_FIRST_LINE = """
import sys
from nutribench.tuning.driver import TuneSettings, tune

class Said(Exception):
    pass

def say(line):
    print("torch" in sys.modules, line)
    raise Said

try:
    tune(TuneSettings("mc", "first", ("run0",), None, trials=1, days=2, db=sys.argv[1]), say)
except Said:
    pass
"""


def test_tune_says_what_it_starts_before_torch_is_imported(tmp_path: Path) -> None:
    """``nutribench tune``'s first line (the study, its trials and agents) comes before torch."""
    result = run_script(_TUNE_FIRST_LINE, str(tmp_path / "nb.db"), cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    torch_loaded, first = result.stdout.strip().split(" ", 1)
    assert first.startswith("tune first: search space mc, until 1 trial is finished"), first
    assert torch_loaded == "False"
