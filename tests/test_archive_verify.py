"""Archives: an archive is a file from anywhere, so ``db import``
checks it whole before a database is opened. Each tampering below is refused with one line
naming the archive and what is wrong, exit status 2, no traceback, and no database file
created (nor an existing one touched); the committed archives of ``reports/paper/`` pass and
still rebuild the tables committed beside them; names read from a database never become
paths without the name check; ``db export`` into a folder that does not exist is one line;
``db import`` into PostgreSQL prints no password."""

from __future__ import annotations

import copy
import hashlib
import io
import json
import sqlite3
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pytest
from typer.testing import CliRunner

from nutribench.cli import app
from nutribench.config.loading import content_sha256
from nutribench.scheduler.driver import GridSettings, run_grid
from nutribench.scheduler.synthetic import synthetic_job
from nutribench.store import read_jobs
from nutribench.store.archive import read_archive, valid_config_name, verify_archive

runner = CliRunner()
ROOT = Path(__file__).resolve().parents[1]
PAPER = ROOT / "reports" / "paper"
H = 50  # the regimes' horizon (reward.horizon)


def _out(res) -> str:
    return " ".join(res.output.split())


def _lines(res) -> list[str]:
    return [line for line in res.output.splitlines() if line.strip()]


@pytest.fixture(scope="module")
def source(tmp_path_factory) -> tuple[Path, Path]:
    """A database of 2 done jobs (run0 x mc, seeds 0 and 1: 3 training and 2 evaluation days
    each) and its archive."""
    folder = tmp_path_factory.mktemp("source")
    db = folder / "src.db"
    run_grid(
        GridSettings(
            db, ["run0"], ["mc"], [0, 1], 3, 2, job_fn=synthetic_job, models_dir=folder / "models", display=False
        )
    )
    with sqlite3.connect(db) as c:  # the 0004 columns, so that they travel
        c.execute("UPDATE jobs SET batch_id = 'b1', batch_size = 2, device = 'cpu'")
    archive = folder / "good.npz"
    res = runner.invoke(app, ["db", "export", str(archive), "--db", str(db)])
    assert res.exit_code == 0, res.output
    return db, archive


def _read(archive: Path) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    with np.load(archive, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    return json.loads(arrays.pop("meta").tobytes().decode()), arrays


def _save(path: Path, meta: dict[str, Any], arrays: dict[str, np.ndarray]) -> None:
    np.savez(path, meta=np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8), **arrays)  # path ends in .npz


def _recount(meta: dict[str, Any], arrays: dict[str, np.ndarray]) -> None:
    """The meta's counts made to agree, so that only the tampering itself is wrong."""
    meta["counts"] = {
        "jobs": len(meta["jobs"]),
        "episodes": len(arrays["episodes.job"]),
        "eval_steps": len(arrays["eval_steps.job"]),
    }


def _keep(arrays: dict[str, np.ndarray], table: str, keep: np.ndarray) -> None:
    for k in [k for k in arrays if k.startswith(f"{table}.")]:
        arrays[k] = arrays[k][keep]


def _rehash(row: dict[str, Any]) -> None:
    row["sha256"] = content_sha256(row["body"])


def _rename_regime(meta: dict[str, Any], name: str) -> None:
    """A regime renamed everywhere, its body and hash consistent: only the name is wrong."""
    old = meta["regimes"][0]["name"]
    meta["regimes"][0]["name"] = name
    meta["regimes"][0]["body"]["regime"]["name"] = name
    _rehash(meta["regimes"][0])
    for job in meta["jobs"]:
        if job["regime"][0] == old:
            job["regime"][0] = name


def _rename_agent(meta: dict[str, Any], name: str) -> None:
    old = meta["agent_configs"][0]["name"]
    meta["agent_configs"][0]["name"] = name
    meta["agent_configs"][0]["body"]["name"] = name
    _rehash(meta["agent_configs"][0])
    for job in meta["jobs"]:
        if job["agent"][0] == old:
            job["agent"][0] = name


def _drop_steps(m, a):  # the audit's case: a done job missing 10 of its evaluation steps
    _keep(
        a,
        "eval_steps",
        ~((a["eval_steps.job"] == 0) & (a["eval_steps.episode"] == 1) & (a["eval_steps.step"] > H - 10)),
    )
    _recount(m, a)


def _drop_train_episode(m, a):
    _keep(a, "episodes", ~((a["episodes.job"] == 1) & (a["episodes.phase"] == "train") & (a["episodes.episode"] == 2)))
    _recount(m, a)


def _drop_eval_episode(m, a):
    _keep(a, "episodes", ~((a["episodes.job"] == 0) & (a["episodes.phase"] == "eval") & (a["episodes.episode"] == 1)))
    _recount(m, a)


def _duplicate_episode(m, a):  # train episode 2 of job 0 renumbered 1: the count is right, a key is twice
    a["episodes.episode"][
        (a["episodes.job"] == 0) & (a["episodes.phase"] == "train") & (a["episodes.episode"] == 2)
    ] = 1


def _duplicate_step(m, a):
    a["eval_steps.step"][(a["eval_steps.job"] == 1) & (a["eval_steps.episode"] == 0) & (a["eval_steps.step"] == 7)] = 8


def _set(key: str, row: int, value: Any) -> Callable:
    def tamper(m, a):
        a[key][row] = value

    return tamper


def _job(field: str, value: Any, job: int = 0) -> Callable:
    def tamper(m, a):
        m["jobs"][job][field] = value

    return tamper


def _delete_job_field(field: str) -> Callable:
    def tamper(m, a):
        del m["jobs"][0][field]

    return tamper


def _nan_in_foods(m, a):
    foods = a["episodes.foods"].astype(np.float64)
    foods[3] = np.nan
    a["episodes.foods"] = foods


def _bad_body(m, a):  # the audit's case: content changed, its sha256 kept
    m["agent_configs"][0]["body"]["learning_rate"] = 0.5


def _body_of_another(m, a):  # content and hash consistent, but the body is another config's
    m["agent_configs"][0]["body"]["version"] = 99
    m["agent_configs"][0]["body"]["max_grad_norm"] = 1.0
    _rehash(m["agent_configs"][0])


def _duplicate_job(m, a):
    m["jobs"].append(copy.deepcopy(m["jobs"][0]))
    _recount(m, a)


def _duplicate_config(m, a):
    m["regimes"].append(copy.deepcopy(m["regimes"][0]))


def _mixed_fake(m, a):
    m["jobs"][0]["fake"] = False


def _bytes(transform: Callable[[bytes], bytes]) -> Callable:
    transform.raw = True  # type: ignore[attr-defined]
    return transform


def _member(data: bytes, name: str) -> zipfile.ZipInfo:
    with zipfile.ZipFile(io.BytesIO(data)) as z:
        return z.getinfo(name)


def _flip_data(member: str) -> Callable:
    """One bit flipped in the middle of a member's compressed bytes."""

    def flip(data: bytes) -> bytes:
        info = _member(data, member)
        start = (
            info.header_offset
            + 30
            + len(info.filename.encode())
            + int.from_bytes(data[info.header_offset + 28 : info.header_offset + 30], "little")
        )
        b = bytearray(data)
        b[start + info.compress_size // 2] ^= 0x10
        return bytes(b)

    return _bytes(flip)


def _flip_crc(member: str) -> Callable:
    """One bit flipped in a member's CRC-32 in the central directory."""

    def flip(data: bytes) -> bytes:
        with zipfile.ZipFile(io.BytesIO(data)) as z:
            start = z.start_dir
        at = data.index(b"PK\x01\x02", start)
        while data[at + 46 : at + 46 + len(member)] != member.encode():
            at = data.index(b"PK\x01\x02", at + 4)
        b = bytearray(data)
        b[at + 16] ^= 0x01
        return bytes(b)

    return _bytes(flip)


def _npy_bytes() -> bytes:
    buf = io.BytesIO()
    np.save(buf, np.arange(3))
    return buf.getvalue()


#: tampering -> (what it does to (meta, arrays) or to the file's bytes, words of the error line)
TAMPERINGS: dict[str, tuple[Callable, str]] = {
    "empty file": (_bytes(lambda b: b""), "the file is empty"),
    "truncated": (_bytes(lambda b: b[: len(b) // 2]), "not a results archive"),
    "truncated to its head": (_bytes(lambda b: b[:100]), "not a results archive"),
    "a bit flipped in a column": (_flip_data("episodes.return.npy"), "not a results archive"),
    "a bit flipped in the meta": (_flip_data("meta.npy"), "not a results archive"),
    "a bit flipped in a checksum": (_flip_crc("eval_steps.reward.npy"), "not a results archive"),
    "a .npy file": (_bytes(lambda b: _npy_bytes()), "a single array"),
    "not a zip": (_bytes(lambda b: b"PK\x03\x04 but not really a zip file" * 10), "not a results archive"),
    "meta not JSON": (lambda m, a: None, "not JSON"),  # special-cased in _write_tampered
    "no meta": (lambda m, a: None, "no meta"),  # special-cased
    "an object array": (lambda m, a: None, "not a results archive"),  # special-cased
    "another format": (lambda m, a: m.update(format="something-else"), "format 'something-else'"),
    "a newer format version": (lambda m, a: m.update(format_version=2), "v2, this nutribench reads"),
    "a column removed": (lambda m, a: a.pop("episodes.return"), "column episodes.return is missing"),
    "the job column removed": (lambda m, a: a.pop("eval_steps.job"), "eval_steps.job is missing"),
    "a column shortened": (
        lambda m, a: a.update({"eval_steps.C": a["eval_steps.C"][:-1]}),
        "eval_steps.C has 199 rows",
    ),
    "a column of another type": (
        lambda m, a: a.update({"episodes.return": a["episodes.return"].astype(np.float32)}),
        "float32, not float64",
    ),
    "a 2-d column": (lambda m, a: a.update({"eval_steps.F": a["eval_steps.F"].reshape(2, -1)}), "not a column"),
    "NaN in foods": (_nan_in_foods, "episodes.foods holds float64, not integers"),
    "NaN in a return": (_set("episodes.return", 2, np.nan), "episodes.return holds NaN in row 2"),
    "infinity in a reward": (_set("eval_steps.reward", 5, -np.inf), "eval_steps.reward holds -inf in row 5"),
    "a NULL mask where NULL is not allowed": (
        lambda m, a: a.update({"episodes.return.null": np.zeros(len(a["episodes.return"]), bool)}),
        "does not allow",
    ),
    "an array the format does not have": (
        lambda m, a: a.update({"episodes.extra": np.zeros(len(a["episodes.job"]))}),
        "not part of the format",
    ),
    "a job index out of range": (_set("episodes.job", 4, 2), "belongs to job 2, but the archive has 2 jobs"),
    "a negative job index": (_set("eval_steps.job", 9, -1), "belongs to job -1"),
    "a job missing 10 evaluation steps": (_drop_steps, "has 90 evaluation steps, not 2 days x 50 = 100"),
    "a job missing a training episode": (_drop_train_episode, "has 2 training episodes, its budget is 3"),
    "a job missing an evaluation episode": (_drop_eval_episode, "has 1 evaluation episodes, not its 2"),
    "a training episode beyond the budget": (_set("episodes.episode", 2, 3), "out of its range 0..2"),
    "a duplicate episode": (_duplicate_episode, "is there twice"),
    "a duplicate evaluation step": (_duplicate_step, "is there twice"),
    "a step beyond the horizon": (_set("eval_steps.step", 0, H + 1), "step 51 of job 0 is out of its range 1..50"),
    "an unknown food": (_set("eval_steps.food", 0, 999), "food 999"),
    "an action that is no action": (_set("eval_steps.action", 0, 2), "action 2"),
    "more foods than steps": (_set("episodes.foods", 1, H + 1), "51 foods in a day of 50 steps"),
    "a NULL mask removed": (
        lambda m, a: a.pop("episodes.first_overshoot_step.null"),
        "first_overshoot_step -1 is out of its range 1..50",
    ),
    "an unknown phase": (_set("episodes.phase", 0, "test"), "phase 'test'"),
    "an unknown status": (_job("status", "weird"), "unknown status"),
    "a job not done": (_job("status", "pending"), "done jobs only"),
    "an unknown engine": (_job("engine", "warp"), "engine 'warp' is unknown"),
    "a job field of another type": (_job("seed", "0"), "seed = '0' is not a valid int"),
    "a job field missing": (_delete_job_field("episodes"), "field 'episodes' is missing"),
    "a job field the format does not have": (_job("owner", "elsewhere:1:x"), "unknown field 'owner'"),
    "a job of a config the archive lacks": (_job("regime", ["run9", 2]), "'run9' v2 is not among"),
    "a duplicate job": (_duplicate_job, "listed twice"),
    "a duplicate config": (_duplicate_config, "listed twice"),
    "a config's content changed, its sha256 kept": (_bad_body, "does not hash to its sha256"),
    "a config's sha256 changed": (lambda m, a: m["regimes"][0].update(sha256="0" * 64), "does not hash to its sha256"),
    "a body describing another config": (_body_of_another, "describes 'mc' v99"),
    "a regime name that is a path": (lambda m, a: _rename_regime(m, "../../etc/x/evil"), "is not a name"),
    "an absolute path as agent name": (lambda m, a: _rename_agent(m, "/etc/passwd"), "is not a name"),
    "an agent name with capitals": (lambda m, a: _rename_agent(m, "PPO"), "is not a name"),
    "a name of 65 characters": (lambda m, a: _rename_agent(m, "a" * 65), "at most 64 characters"),
    "a name ending in a newline": (lambda m, a: _rename_agent(m, "mc\n"), "is not a name"),
    "meta counts too many episodes": (
        lambda m, a: m["counts"].update(episodes=m["counts"]["episodes"] + 25),
        "meta says 35 episodes, the archive holds 10",
    ),
    "meta counts fewer jobs": (lambda m, a: m["counts"].update(jobs=1), "meta says 1 jobs"),
    "a dry run's jobs mixed with real ones": (_mixed_fake, "mixes a dry run's jobs"),
    "an unknown meta field": (lambda m, a: m.update(extra=1), "unknown field 'extra'"),
}


def _write_tampered(good: Path, name: str, out: Path) -> None:
    tamper, _ = TAMPERINGS[name]
    if getattr(tamper, "raw", False):
        out.write_bytes(tamper(good.read_bytes()))
        return
    meta, arrays = _read(good)
    if name == "meta not JSON":
        np.savez(out, meta=np.frombuffer(b"{not json", dtype=np.uint8), **arrays)
    elif name == "no meta":
        np.savez(out, **arrays)
    elif name == "an object array":
        np.savez(
            out,
            meta=np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8),
            x=np.array([{"a": 1}], dtype=object),
            **arrays,
        )
    else:
        tamper(meta, arrays)
        _save(out, meta, arrays)


@pytest.mark.parametrize("name", list(TAMPERINGS))
def test_each_tampering_is_one_line_exit_2_and_no_database(source, tmp_path, name) -> None:
    _, good = source
    bad = tmp_path / "tampered.npz"
    _write_tampered(good, name, bad)
    db = tmp_path / "new.db"
    res = runner.invoke(app, ["db", "import", str(bad), "--db", str(db)])
    assert res.exit_code == 2, res.output
    assert not isinstance(res.exception, Exception) or isinstance(res.exception, SystemExit), res.exception
    assert "Traceback" not in res.output and len(_lines(res)) == 1, res.output
    line = _out(res)
    assert line.startswith("error: db import:") and str(bad) in line, line  # names the archive
    assert TAMPERINGS[name][1] in line, line
    assert not db.exists() and list(tmp_path.iterdir()) == [bad]  # no database, no -wal, nothing


@pytest.mark.slow
def test_no_bit_flip_imports_other_data(source, tmp_path) -> None:
    """A bit flipped anywhere in the file (every 23rd byte, headers, data and the central
    directory): the archive is refused with one line, or, where the flip hit a zip field no
    reader uses (a local header's time or copy of the CRC), what it reads is exactly the
    untouched archive's content."""
    from nutribench.store import StoreError

    _, good = source
    data = good.read_bytes()
    meta, arrays = read_archive(good)
    refused = accepted = 0
    for pos in range(0, len(data), 23):
        b = bytearray(data)
        b[pos] ^= 0x10
        bad = tmp_path / "flipped.npz"
        bad.write_bytes(bytes(b))
        try:
            m, a = read_archive(bad)
        except StoreError as e:
            assert "\n" not in str(e) and str(bad) in str(e)
            refused += 1
            continue
        accepted += 1
        assert m == meta and set(a) == set(arrays), pos
        for k in a:
            assert a[k].dtype == arrays[k].dtype and np.array_equal(
                a[k], arrays[k], equal_nan=a[k].dtype.kind == "f"
            ), (pos, k)
    assert refused > 4 * accepted  # most bytes are data


def test_a_tampered_archive_leaves_an_existing_database_untouched(source, tmp_path) -> None:
    src, good = source
    dst = tmp_path / "dst.db"
    assert runner.invoke(app, ["db", "import", str(good), "--db", str(dst)]).exit_code == 0
    before = hashlib.sha256(dst.read_bytes()).hexdigest()
    for name in ("a job missing 10 evaluation steps", "a config's content changed, its sha256 kept", "truncated"):
        bad = tmp_path / "bad.npz"
        _write_tampered(good, name, bad)
        res = runner.invoke(app, ["db", "import", str(bad), "--db", str(dst)])
        assert res.exit_code == 2 and len(_lines(res)) == 1, res.output
    assert hashlib.sha256(dst.read_bytes()).hexdigest() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.npz", "dst.db"]


def test_the_untampered_archive_imports_and_carries_the_new_columns(source, tmp_path) -> None:
    """The control: the same archive, untouched, imports; 0004's columns travel, the stored
    model path does not (an archive carries no model; a path from elsewhere is not trusted)."""
    src, good = source
    assert read_jobs(src)["model_path"].notna().all()
    dst = tmp_path / "dst.db"
    res = runner.invoke(app, ["db", "import", str(good), "--db", str(dst)])
    assert res.exit_code == 0 and "2 jobs imported (10 episodes, 200 evaluation steps)" in _out(res), res.output
    jobs = read_jobs(dst)
    assert list(jobs["fake"]) == [True, True]  # a dry run's jobs stay a dry run's
    assert set(jobs["batch_id"]) == {"b1"} and set(jobs["batch_size"]) == {2} and set(jobs["device"]) == {"cpu"}
    assert jobs["model_path"].isna().all()
    # a model path planted in the archive is not stored either
    meta, arrays = _read(good)
    meta["jobs"][0]["model_path"] = "/etc/passwd"
    planted, dst2 = tmp_path / "planted.npz", tmp_path / "dst2.db"
    _save(planted, meta, arrays)
    assert runner.invoke(app, ["db", "import", str(planted), "--db", str(dst2)]).exit_code == 0
    assert read_jobs(dst2)["model_path"].isna().all()


@pytest.fixture(scope="module")
def real(tmp_path_factory) -> tuple[Path, Path]:
    """An archive of real results (two recorded jobs): their evaluation days replay."""
    from tests.recorded import recorded_archive

    return recorded_archive(tmp_path_factory.mktemp("real"))


def test_an_archive_written_before_revision_0004_imports_with_its_defaults(real, tmp_path) -> None:
    _, good = real
    meta, arrays = _read(good)
    for job in meta["jobs"]:
        for field in ("fake", "batch_id", "batch_size", "device", "source", "source_sha256"):
            del job[field]
    old = tmp_path / "old.npz"
    _save(old, meta, arrays)
    dst = tmp_path / "dst.db"
    assert runner.invoke(app, ["db", "import", str(old), "--db", str(dst)]).exit_code == 0
    jobs = read_jobs(dst)
    assert list(jobs["fake"]) == [False, False]
    assert jobs[["batch_id", "batch_size", "device", "source", "source_sha256"]].isna().all().all()


def test_a_dry_runs_archive_is_not_mixed_into_real_results(source, real, tmp_path) -> None:
    _, good = source
    dst = tmp_path / "dst.db"
    assert runner.invoke(app, ["db", "import", str(real[1]), "--db", str(dst)]).exit_code == 0
    before = hashlib.sha256(dst.read_bytes()).hexdigest()
    res = runner.invoke(app, ["db", "import", str(good), "--db", str(dst)])
    assert res.exit_code == 2 and len(_lines(res)) == 1 and "never mixed" in _out(res), res.output
    assert hashlib.sha256(dst.read_bytes()).hexdigest() == before


def test_a_failed_import_removes_the_database_file_it_created(source, tmp_path, monkeypatch) -> None:
    """A failure after the archive passed (here: the rows found after the writes disagree) rolls
    back, and the SQLite file the import created is gone again."""
    from nutribench.store.archive import merge

    _, good = source
    monkeypatch.setattr(merge, "_chunks", lambda ids, n=500: [ids[:1]])  # counts only the first job back
    dst = tmp_path / "new.db"
    res = runner.invoke(app, ["db", "import", str(good), "--db", str(dst)])
    assert res.exit_code == 2 and "nothing imported" in _out(res) and len(_lines(res)) == 1, res.output
    assert list(tmp_path.iterdir()) == []


def test_export_checks_what_it_writes(source, tmp_path) -> None:
    """A database whose done job lacks evaluation steps is named at export, and no file is written."""
    src, _ = source
    db = tmp_path / "broken.db"
    db.write_bytes(src.read_bytes())
    with sqlite3.connect(db) as c:
        c.execute("DELETE FROM eval_steps WHERE job_id = 2 AND episode = 1 AND step > 40")
    res = runner.invoke(app, ["db", "export", str(tmp_path / "a.npz"), "--db", str(db)])
    assert res.exit_code == 2 and len(_lines(res)) == 1, res.output
    assert "cannot be exported" in _out(res) and "seed 1" in _out(res) and "90 evaluation steps" in _out(res)
    assert not (tmp_path / "a.npz").exists() and not list(tmp_path.glob("*.tmp*"))


@pytest.mark.parametrize(
    "out, words", [("/nonexistent/o.npz", "folder /nonexistent does not exist"), (".", "is a folder")]
)
def test_export_to_a_place_it_cannot_write_is_one_line(source, tmp_path, monkeypatch, out, words) -> None:
    src, _ = source
    monkeypatch.chdir(tmp_path)
    res = runner.invoke(app, ["db", "export", out, "--db", str(src)])
    assert res.exit_code == 2 and len(_lines(res)) == 1 and "Traceback" not in res.output, res.output
    assert words in _out(res)
    assert list(tmp_path.iterdir()) == []


def test_import_into_postgresql_prints_no_password(source, pg_url) -> None:
    _, good = source
    url = pg_url.replace(
        "postgresql+psycopg://nutribench@", "postgresql+psycopg://nutribench:s3cret@"
    )  # trust auth ignores it
    res = runner.invoke(app, ["db", "import", str(good), "--db", url])
    assert res.exit_code == 0, res.output
    assert "s3cret" not in res.output and "nutribench:***@" in _out(res) and "2 jobs imported" in _out(res)


# --------------------------------------------------------------------------- names -> paths
def test_the_name_check() -> None:
    assert valid_config_name("run0") and valid_config_name("gru_ppo") and valid_config_name("a" * 64)
    for bad in ("", "Run0", "0run", "../x", "/etc/passwd", "a-b", "a.b", "mc\n", "a" * 65, None, 3):
        assert not valid_config_name(bad), bad


@pytest.fixture
def evil_db(source, tmp_path) -> Path:
    """A database (real jobs, so the views draw them) whose regime was renamed to a path."""
    src, _ = source
    db = tmp_path / "evil.db"
    db.write_bytes(src.read_bytes())
    with sqlite3.connect(db) as c:
        c.execute("UPDATE jobs SET fake = 0")
        c.execute("UPDATE regimes SET name = '../../etc/x/evil'")
    return db


def test_report_refuses_a_stored_name_that_is_a_path(evil_db, tmp_path) -> None:
    out = tmp_path / "out"
    for args in (["--fig", "3"], ["--table", "results"], ["--all"]):
        res = runner.invoke(app, ["report", *args, "--db", str(evil_db), "--out", str(out)])
        assert res.exit_code == 2 and len(_lines(res)) == 1 and "Traceback" not in res.output, (args, res.output)
        assert "regime '../../etc/x/evil' is not a name" in _out(res), res.output
    res = runner.invoke(
        app,
        [
            "report",
            "--trajectory",
            "--algo",
            "mc",
            "--regime",
            "../../etc/x/evil",
            "--seed",
            "0",
            "--db",
            str(evil_db),
            "--out",
            str(out),
        ],
    )
    assert (
        res.exit_code == 2
        and len(_lines(res)) == 1
        and "--regime: regime '../../etc/x/evil' is not a name" in _out(res)
    ), res.output
    assert not out.exists() and not (tmp_path / "etc").exists()


def test_report_refuses_a_stored_agent_name_that_is_a_path(evil_db, tmp_path) -> None:
    with sqlite3.connect(evil_db) as c:
        c.execute("UPDATE regimes SET name = 'run0'")
        c.execute("UPDATE agent_configs SET name = '../mine'")
    out = tmp_path / "out"
    res = runner.invoke(app, ["report", "--table", "7", "--db", str(evil_db), "--out", str(out)])
    assert res.exit_code == 2 and len(_lines(res)) == 1 and "agent config '../mine' is not a name" in _out(res), (
        res.output
    )
    res = runner.invoke(app, ["report", "--fig", "4", "--pair", "../mine,ppo", "--db", str(evil_db), "--out", str(out)])
    assert res.exit_code == 2 and len(_lines(res)) == 1 and "is not a name" in _out(res), res.output
    assert not out.exists()


# --------------------------------------------------------------------------- the committed archives
COMMITTED = sorted(PAPER.glob("data/*.npz")) + sorted((ROOT / "reports").glob("quick/**/*.npz"))


@pytest.mark.parametrize("archive", COMMITTED, ids=lambda p: p.name)
def test_the_committed_archives_pass_every_check(archive) -> None:
    meta, _ = read_archive(archive)
    counts = verify_archive(archive)
    assert counts["episodes"] == counts["jobs"] * (5000 + 5) and counts["eval_steps"] == counts["jobs"] * 5 * H
    assert all("fake" not in j for j in meta["jobs"])  # written before revision 0004


@pytest.mark.slow
def test_a_committed_archive_still_imports_and_rebuilds_its_tables(tmp_path) -> None:
    """``sac-run4-run6.npz`` (the smallest part: 15 jobs) into an empty database, then the
    results and the training tables as README's ``report --all`` builds them: the rows of
    those regimes and of sac equal the committed ``table_results.csv`` and
    ``table_training_vs_authors.csv``. (Only this part is rebuilt, to keep the test at about
    15 s; the other five pass :func:`test_the_committed_archives_pass_every_check`.)"""
    from nutribench.report.build import build_table, load_report_data

    archive, db = PAPER / "data" / "sac-run4-run6.npz", tmp_path / "paper.db"
    res = runner.invoke(app, ["db", "import", str(archive), "--db", str(db)])
    assert res.exit_code == 0 and "15 jobs imported (75,075 episodes, 3,750 evaluation steps)" in _out(res), res.output
    jobs = read_jobs(db)
    assert (~jobs["fake"]).all() and jobs[["batch_id", "device", "source", "model_path"]].isna().all().all()
    with sqlite3.connect(db) as c:
        per_job = c.execute("SELECT job_id, phase, count(*) FROM episodes GROUP BY job_id, phase").fetchall()
        steps = c.execute("SELECT job_id, count(*) FROM eval_steps GROUP BY job_id").fetchall()
    assert {(p, n) for _, p, n in per_job} == {("train", 5000), ("eval", 5)} and len(per_job) == 30
    assert {n for _, n in steps} == {250} and len(steps) == 15
    data = load_report_data(db)
    for key, stem in (("results", "table_results"), ("training", "table_training_vs_authors")):
        built = pd.read_csv(io.StringIO(build_table(key, data).to_csv()))
        committed = pd.read_csv(PAPER / f"{stem}.csv")
        committed = committed[(committed["algo"] == "sac") & committed["regime"].isin(["run4", "run5", "run6"])]
        assert len(built) == 3
        # every column to the digit, the intervals included: the seed-level t intervals and the
        # IQM's enumerated resamples are each cell's own (no draw shared across the table's
        # cells), so a table of three cells prints what the whole table printed
        cols = list(committed.columns)
        assert len(cols) >= 8 and any(c.endswith("_iqm_lo") for c in cols) == (key == "results")
        pd.testing.assert_frame_equal(
            built[cols].reset_index(drop=True), committed[cols].reset_index(drop=True), check_exact=False, rtol=1e-12
        )
