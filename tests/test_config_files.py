"""Regime, catalog and reward files: validation messages, regeneration, hashing, CLI errors."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from nutribench.cli import app
from nutribench.config import ConfigError, list_regimes, load_env_config
from nutribench.config.generate import regenerate, regime_to_toml
from tests.conftest import CATALOG, REGIME, REWARD, write_regime_dir

runner = CliRunner()


def test_shipped_regimes_load_and_match_a_fresh_draw():
    assert list_regimes() == [f"run{k}" for k in range(7)]
    hashes = set()
    for name in list_regimes():
        cfg = load_env_config(name)
        assert regenerate(cfg.regime, cfg.catalog).foods == cfg.regime.foods
        assert len(cfg.regime.foods) == len(cfg.catalog.food) == 10
        hashes.add(cfg.sha256)
    assert len(hashes) == 7
    run0 = load_env_config("run0")
    assert (run0.tau() == 0).all() and (run0.sigma() == 0).all()


#: The shipped regimes' content hashes as the archives of reports/paper and
#: reports/sensitivity store them: an option added to the files must not change them.
STORED_SHA256 = {
    "run0": "c063eb88421b26c24fc4f96a73d46d4524f32d9ff38e9dfdb4c81f1554629418",
    "run3": "d7c1d49a4e0396aebbbab3dfe1e30340b9c3dfdb2c102b72e4d909ed3e109385",
    "run6": "8db4cf13a016e92b360a27c11f1d6ec5d014258839a47916c7840be55584ac75",
}


def test_shipped_hashes_are_the_stored_ones_and_the_clock_changes_the_hash(tmp_path):
    for name, sha in STORED_SHA256.items():
        assert load_env_config(name).sha256 == sha
    cfg = load_env_config("run3")
    assert cfg.regime.observe_clock is False and "observe_clock" not in cfg.content()["regime"]
    for name in ("foods.toml", "reward.toml"):
        (tmp_path / name).write_text((cfg.path.parent / name).read_text())
    text = cfg.path.read_text()
    (tmp_path / "run3.toml").write_text(
        text.replace('reward = "reward.toml"', 'reward = "reward.toml"\nobserve_clock = false')
    )
    assert load_env_config(tmp_path / "run3.toml").sha256 == cfg.sha256  # written out off: the same regime
    (tmp_path / "run3.toml").write_text(
        text.replace('reward = "reward.toml"', 'reward = "reward.toml"\nobserve_clock = true')
    )
    clock = load_env_config(tmp_path / "run3.toml")
    assert clock.regime.observe_clock is True and clock.content()["regime"]["observe_clock"] is True
    assert clock.sha256 != cfg.sha256
    (tmp_path / "run3.toml").write_text(regime_to_toml(clock.regime))
    assert load_env_config(tmp_path / "run3.toml").sha256 == clock.sha256  # the writer keeps the option


def test_regime_file_round_trips_through_the_writer(tmp_path):
    cfg = load_env_config("run4")
    for name in ("foods.toml", "reward.toml"):
        (tmp_path / name).write_text((cfg.path.parent / name).read_text())
    (tmp_path / "run4.toml").write_text(regime_to_toml(cfg.regime))
    again = load_env_config(tmp_path / "run4.toml")
    assert again.regime == cfg.regime
    assert again.sha256 == cfg.sha256


def test_hash_ignores_formatting_but_not_content(tiny_regime):
    a = load_env_config(tiny_regime).sha256
    tiny_regime.write_text("# a comment\n" + tiny_regime.read_text())
    assert load_env_config(tiny_regime).sha256 == a
    tiny_regime.write_text(tiny_regime.read_text().replace("P = 2.6", "P = 2.7"))
    assert load_env_config(tiny_regime).sha256 != a


BAD = [
    (
        "negative sigma",
        lambda r, c: (r.replace("sigma = { C = 0.0, F = 1.0", "sigma = { C = 0.0, F = -1.0"), c),
        "tiny.toml",
        "foods.b.sigma.F",
    ),
    (
        "missing tau",
        lambda r, c: (r.replace("tau = { C = 1.0, F = 0.0, P = 0.0 }, ", ""), c),
        "tiny.toml",
        "foods.a.tau",
    ),
    (
        "missing tau value",
        lambda r, c: (r.replace("tau = { C = 1.0, F = 0.0, P = 0.0 }", "tau = { C = 1.0, F = 0.0 }"), c),
        "tiny.toml",
        "foods.a.tau.P",
    ),
    ("unknown key", lambda r, c: (r.replace("seed = 0", "seed = 0\ncolour = 3"), c), "tiny.toml", "colour"),
    ("version missing", lambda r, c: (r.replace("version = 1\n", ""), c), "tiny.toml", "version"),
    (
        "catalog size mismatch",
        lambda r, c: (
            r,
            c
            + '\n[[food]]\nkey = "c"\nname = "c"\nportion = "1"\nportion_g = 1.0\nper_100g = { C = 1.0, F = 1.0, P = 1.0 }\nsource_id = "x"\n',
        ),
        "tiny.toml",
        "catalog size mismatch",
    ),
    ("value outside its range", lambda r, c: (r.replace("P = 2.6", "P = 7.0"), c), "tiny.toml", "outside ranges.tau.P"),
    (
        "catalog unknown key",
        lambda r, c: (r, c.replace('source_id = "test-a"', 'source_id = "test-a"\nfiber = 2.0')),
        "foods.toml",
        "food.0.fiber",
    ),
    ("not TOML", lambda r, c: (r + "\n[[[", c), "tiny.toml", "not valid TOML"),
]


@pytest.mark.parametrize("label,mutate,file,field", BAD, ids=[b[0] for b in BAD])
def test_bad_files_fail_with_one_line_naming_file_and_field(tmp_path, label, mutate, file, field):
    regime, catalog = mutate(REGIME, CATALOG)
    path = write_regime_dir(tmp_path / "regimes", regime=regime, catalog=catalog, reward=REWARD)
    with pytest.raises(ConfigError) as err:
        load_env_config(path)
    msg = str(err.value)
    assert "\n" not in msg
    assert file in msg and field in msg, msg
    # and the CLI: one line on stderr, exit code 2, no traceback
    result = runner.invoke(app, ["regimes", "check", "--regimes", str(path)])
    assert result.exit_code == 2
    assert "Traceback" not in result.output
    assert field in result.output


def test_unknown_regime_lists_the_known_ones():
    with pytest.raises(ConfigError, match="known regimes are run0, run1"):
        load_env_config("run9")
    result = runner.invoke(app, ["baselines", "--regimes", "run0,run9", "--episodes", "2"])
    assert result.exit_code == 2 and "run9" in result.output and "run0" in result.output


def test_regimes_generate_prints_the_file():
    result = runner.invoke(app, ["regimes", "generate", "run3"])
    assert result.exit_code == 0
    assert result.output == load_env_config("run3").path.read_text()


@pytest.mark.parametrize(
    ("mutate", "expected"),
    [
        (lambda t: t.replace("[ranges]", "x = [\n[ranges]"), r"run3\.toml: not valid TOML: .*line \d+"),  # syntax error
        (lambda t: t.replace("[foods]", "[food_values]"), r"run3\.toml: .*foods"),  # a renamed table
    ],
)
def test_a_broken_regime_file_fails_check_and_run_instead_of_leaving_the_grid(tmp_path, monkeypatch, mutate, expected):
    """A regime file that does not parse is not skipped by the listing (where `regimes check`
    would say ok for the other six and `run` run a six-regime grid with exit 0)."""
    import re
    import shutil

    folder = tmp_path / "regimes"
    shutil.copytree(Path(__file__).resolve().parents[1] / "regimes", folder)
    (folder / "run3.toml").write_text(mutate((folder / "run3.toml").read_text()))
    monkeypatch.setenv("NUTRIBENCH_REGIMES", str(folder))
    check = runner.invoke(app, ["regimes", "check"])
    assert check.exit_code == 2 and re.search(expected, check.output), check.output
    run = runner.invoke(
        app,
        ["run", "--regimes", "all", "--algos", "mc", "--seeds", "0", "--episodes", "2", "--db", str(tmp_path / "r.db")],
        env={"NUTRIBENCH_JOB": "fake"},
    )
    assert run.exit_code == 2 and re.search(expected, run.output), run.output
    assert not (tmp_path / "r.db").exists()


def test_help_keeps_brackets_and_shows_flags_as_flags():
    """The help shows `[ranges]` and `[foods]` (rich markup would eat them) and no `<bool>` on flags."""
    out = runner.invoke(app, ["regimes", "generate", "--help"]).output
    assert "[ranges]" in out and "[foods]" in out
    assert "<bool>" not in out and "--write / --no-write" in out


def test_an_error_line_shows_brackets_as_written(tmp_path):
    """A message holding [..] (a pattern, a TOML table name) was eaten as rich markup:
    "should match pattern '^*$'" instead of "'^[a-z][a-z0-9_]*$'"."""
    text = (Path(__file__).parents[1] / "regimes" / "agents" / "ppo.toml").read_text()
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace('name = "ppo"', 'name = "Bad-Name"'))
    result = runner.invoke(app, ["train", "--algo", str(bad)])
    assert result.exit_code == 2
    assert "'^[a-z][a-z0-9_]*$'" in result.output.replace("\n", "")


def test_every_rooms_user_error_is_one_class():
    """One base class: the CLI turns any of them into one line and exit 2."""
    from nutribench.errors import UserError
    from nutribench.report.build import ReportError
    from nutribench.scheduler.executors import ExecutorError
    from nutribench.scheduler.grid import GridError
    from nutribench.scheduler.registration import RunError
    from nutribench.store import StoreError

    for cls in (ConfigError, StoreError, GridError, ExecutorError, RunError, ReportError):
        assert issubclass(cls, UserError), cls
