"""Issue 52, edges: the fuzz harness (:mod:`tests.test_fuzz`'s settings: derandomized, a few
examples in the default run, all of them under ``-m slow``) over what a user names as an output
and over forged archives.

* **Output targets** given to the commands that write a path: ``db export FILE``, ``report
  --out DIR``, ``leaderboard --out DIR``, ``tune best --write --out DIR``, ``regimes generate
  --write`` (its file in the regimes folder). The targets: a character device (made with
  ``os.mknod`` in the test's own folder, never the machine's /dev), a FIFO, a symbolic link to
  either, an existing file where a folder is wanted, a read-only folder. Each is refused with
  exit 2 and one ``error:`` line, and every entry of the lab is left as it was (its kind, mode,
  link target and bytes). The read-only folder is left out when the tests run as root: root
  ignores permission bits, so the folder takes new files and there is nothing to refuse.
* **Forged archives** given to ``db import``: a regime bearing the shipped name and version
  with other content (one number of its body changed, its sha256 recomputed), evaluation days
  whose foods are not the seed's test days, a zip member twice: each refused in one line, no
  database created.
"""

from __future__ import annotations

import io
import json
import os
import shutil
import stat
import tempfile
import zipfile
from pathlib import Path
from typing import Any
from unittest import mock

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from typer.testing import CliRunner

from nutribench.cli import app
from tests.conftest import one_error_line
from tests.test_fuzz import FAST, REPO, SLOW, fuzz

runner = CliRunner()


def _can_mknod() -> bool:
    with tempfile.TemporaryDirectory() as tmp:
        try:
            os.mknod(Path(tmp) / "d", stat.S_IFCHR | 0o600, os.makedev(1, 3))
        except (PermissionError, OSError):
            return False
    return True


#: a read-only folder refuses new files only to a user that is not root (root ignores the bits)
NOT_ROOT = os.geteuid() != 0
DEVICES = _can_mknod()
SPECIAL = [k for k in ("dev", "fifo", "link_dev", "link_fifo") if DEVICES or "dev" not in k]
#: target kinds per writer: ``file`` writers write one file, ``folder`` writers a folder of files
FILE_KINDS = [*SPECIAL, "below_a_file", *(["read_only"] if NOT_ROOT else [])]
FOLDER_KINDS = [*SPECIAL, "a_file", "below_a_file", *(["read_only"] if NOT_ROOT else [])]
GENERATE_KINDS = [*SPECIAL, *(["read_only"] if NOT_ROOT else [])]


@pytest.fixture(scope="module")
def template(tmp_path_factory) -> Path:
    """A lab: a copy of the regimes and a database of two recorded jobs (real, not dry-run:
    every writer would succeed on a plain target, :func:`test_each_writer_writes_a_plain_target`)."""
    from tests.recorded import recorded_archive

    lab = tmp_path_factory.mktemp("targets")
    shutil.copytree(REPO / "regimes", lab / "regimes")
    recorded_archive(lab)  # real.db, real.npz
    return lab


def _place(lab: Path, kind: str, name: str) -> Path:
    """The target of kind ``kind`` at ``lab/name`` (specials are made in ``lab/specials``)."""
    target = lab / name
    target.parent.mkdir(parents=True, exist_ok=True)
    specials = lab / "specials"
    specials.mkdir(exist_ok=True)
    if kind in ("dev", "link_dev"):
        made = specials / f"dev_{name.replace('/', '_')}"
        os.mknod(made, stat.S_IFCHR | 0o600, os.makedev(1, 3))
    elif kind in ("fifo", "link_fifo"):
        made = specials / f"fifo_{name.replace('/', '_')}"
        os.mkfifo(made)
    elif kind == "a_file":
        target.write_text("a file, not a folder\n")
        return target
    elif kind == "below_a_file":
        (lab / "a_file").write_text("a file, not a folder\n")
        return lab / "a_file" / name
    elif kind == "read_only":
        folder = lab / "ro"
        folder.mkdir(exist_ok=True)
        folder.chmod(0o500)
        return folder / name
    else:
        raise AssertionError(kind)
    if kind.startswith("link"):
        target.symlink_to(made)
    else:
        made.rename(target)
    return target


def state(lab: Path) -> dict[str, Any]:
    """Every entry under ``lab``: its kind and mode, a link's target, a regular file's bytes."""
    out: dict[str, Any] = {}
    for p in sorted(lab.rglob("*")):
        st_ = os.lstat(p)
        what: Any = (stat.S_IFMT(st_.st_mode), stat.S_IMODE(st_.st_mode))
        if stat.S_ISLNK(st_.st_mode):
            what += (os.readlink(p),)
        elif stat.S_ISREG(st_.st_mode):
            what += (p.read_bytes(),)
        out[str(p.relative_to(lab))] = what
    return out


def _fake_study():
    """``tune best`` on a study that needs no training: its best trial is the shipped mc config."""
    from nutribench.agents.config import load_agent_config

    cfg = load_agent_config("mc").model_copy(update={"name": "mc_tuned", "version": 1})
    return mock.patch.multiple("nutribench.tuning.export", tuned_config=lambda *a: (cfg, "# tuned")), mock.patch(
        "nutribench.tuning.study.open_study", lambda *a: None
    )


#: writer -> (the target kinds it meets, the target's name in the lab, its command line)
WRITERS = {
    "db export": (FILE_KINDS, "out.npz", lambda t: ["db", "export", str(t), "--db", "real.db"]),
    "report --out": (
        FOLDER_KINDS,
        "rep",
        lambda t: ["report", "--table", "results", "--db", "real.db", "--out", str(t)],
    ),
    "leaderboard --out": (
        FOLDER_KINDS,
        "lb",
        lambda t: ["leaderboard", "--db", "real.db", "--reps", "100", "--out", str(t)],
    ),
    "tune best --out": (FOLDER_KINDS, "agents", lambda t: ["tune", "best", "--study", "s", "--write", "--out", str(t)]),
    "regimes generate --write": (
        GENERATE_KINDS,
        "regimes/run8.toml",
        lambda t: ["regimes", "generate", "run8", "--from", "run6", "--tau", "C=10-12", "--write"],
    ),
}
CASES = [(w, k) for w, (kinds, _, _) in WRITERS.items() for k in kinds]


def _invoke_in(lab: Path, args: list[str]):
    saved = Path.cwd()
    env = {"NUTRIBENCH_REGIMES": str(lab / "regimes")}
    os.chdir(lab)
    try:
        study, open_study = _fake_study()
        with mock.patch.dict(os.environ, env), study, open_study:
            os.environ.pop("NUTRIBENCH_DB", None)
            os.environ.pop("NUTRIBENCH_AGENTS", None)
            return runner.invoke(app, args)
    finally:
        os.chdir(saved)


def _restore_modes(lab: Path) -> None:
    for p in lab.rglob("*"):
        if p.is_dir() and not p.is_symlink():
            p.chmod(0o700)


def check_target(template: Path, where: Path, writer: str, kind: str) -> None:
    if where.exists():
        _restore_modes(where)
        shutil.rmtree(where)
    lab = shutil.copytree(template, where)
    _, name, command = WRITERS[writer]
    if kind == "read_only" and writer == "regimes generate --write":
        target = lab / name
        (lab / "regimes").chmod(0o500)
    else:
        target = _place(lab, kind, name)
    before = state(lab)
    try:
        line = one_error_line(_invoke_in(lab, command(target)))
        assert state(lab) == before, (writer, kind, line, "the target or the lab was changed by a refusal")
    finally:
        _restore_modes(lab)
    shown = target if kind not in ("below_a_file",) else lab / "a_file"
    assert str(shown) in line or str(shown.relative_to(lab)) in line, (writer, kind, line)


@fuzz(2 * FAST)
@given(case=st.sampled_from(CASES))
def test_fuzz_output_targets(template, tmp_path_factory, case):
    check_target(template, tmp_path_factory.getbasetemp() / "fuzz-target", *case)


@pytest.mark.slow
@pytest.mark.parametrize("case", CASES, ids=[f"{w}-{k}" for w, k in CASES])
def test_every_output_target(template, tmp_path_factory, case):
    check_target(template, tmp_path_factory.getbasetemp() / "every-target", *case)


@pytest.mark.skipif(not NOT_ROOT, reason="root ignores permission bits: a read-only folder takes new files")
def test_read_only_folders_are_among_the_targets():
    assert "read_only" in FILE_KINDS and "read_only" in FOLDER_KINDS


@pytest.mark.parametrize("writer", sorted(WRITERS))
def test_each_writer_writes_a_plain_target(template, tmp_path_factory, writer):
    """The writers succeed on a new name in the lab: their refusals above are the target's doing."""
    lab = tmp_path_factory.getbasetemp() / "plain-target"
    if lab.exists():
        shutil.rmtree(lab)
    shutil.copytree(template, lab)
    _, name, command = WRITERS[writer]
    res = _invoke_in(lab, command(lab / name))
    assert res.exit_code == 0, (writer, res.output)
    assert (lab / name).exists()


# --------------------------------------------------------------------------- forged archives
def _read(archive: Path) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    with np.load(archive, allow_pickle=False) as z:
        arrays = {k: z[k].copy() for k in z.files}
    return json.loads(arrays.pop("meta").tobytes().decode()), arrays


def _save(path: Path, meta: dict[str, Any], arrays: dict[str, np.ndarray]) -> Path:
    np.savez(path, meta=np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8), **arrays)
    return path


def _numbers(body: Any, prefix: tuple = ()) -> list[tuple]:
    """The key paths of the numbers of a config body (dicts only)."""
    out = []
    if isinstance(body, dict):
        for k, v in body.items():
            if isinstance(v, (int, float)) and not isinstance(v, bool):
                out.append((*prefix, k))
            out += _numbers(v, (*prefix, k))
    return out


@st.composite
def forged_regime(draw, meta: dict[str, Any]) -> tuple[dict[str, Any], str]:
    """The archive's run0 v2 with one number of its body changed and its sha256 recomputed."""
    import copy

    from nutribench.config.loading import content_sha256

    meta = copy.deepcopy(meta)
    regime = meta["regimes"][0]
    path = draw(st.sampled_from(_numbers(regime["body"])))
    parent = regime["body"]
    for k in path[:-1]:
        parent = parent[k]
    old = parent[path[-1]]
    parent[path[-1]] = draw(st.sampled_from([old + 1, old * 2 + 1, -old - 1]))
    regime["sha256"] = content_sha256(regime["body"])
    return meta, "regime"


def _eval_rows(arrays: dict[str, np.ndarray]) -> np.ndarray:
    return np.lexsort((arrays["eval_steps.step"], arrays["eval_steps.episode"], arrays["eval_steps.job"]))


@st.composite
def forged_archive(draw, archive: Path, where: Path) -> tuple[Path, tuple[str, ...]]:
    """A forged copy of ``archive`` at ``where`` and words its refusal must hold."""
    from nutribench.config.loading import load_env_config

    meta, arrays = _read(archive)
    how = draw(st.sampled_from(["regime", "foods", "member twice"]))
    if how == "regime":
        meta, _ = draw(forged_regime(meta))
        return _save(where, meta, arrays), ("regime",)
    if how == "foods":
        rows = _eval_rows(arrays)
        k = draw(st.integers(0, len(rows) - 1))
        food = arrays["eval_steps.food"]
        n_foods = len(load_env_config("run0").catalog.food)  # another food of the catalog: in range
        food[rows[k]] = (food[rows[k]] + draw(st.integers(1, n_foods - 1))) % n_foods
        return _save(where, meta, arrays), ("evaluation day", "not the test day")
    # a member twice: the first or the last copy forged (another source, or the genuine bytes)
    with zipfile.ZipFile(archive) as src:
        names = src.namelist()
        twice = draw(st.sampled_from(names))
        extra = src.read(twice)
        if twice == "meta.npy" and draw(st.booleans()):
            meta["source"] = "forged"
            buf = io.BytesIO()
            np.lib.format.write_array(buf, np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8))
            extra = buf.getvalue()
        first = draw(st.booleans())
        with zipfile.ZipFile(where, "w") as dst, pytest.warns(UserWarning, match="Duplicate"):
            if first:
                dst.writestr(twice, extra)
            for info in src.infolist():
                dst.writestr(info, src.read(info))
            if not first:
                dst.writestr(twice, extra)
    return where, (f"member '{twice}' is there twice",)


@pytest.fixture(scope="module")
def genuine(template) -> Path:
    return template / "real.npz"


def check_forged(data, genuine: Path, where: Path) -> None:
    if where.exists():
        shutil.rmtree(where)
    where.mkdir(parents=True)
    archive, words = data.draw(forged_archive(genuine, where / "forged.npz"))
    db = where / "x.db"
    line = one_error_line(runner.invoke(app, ["db", "import", str(archive), "--db", str(db)]))
    assert all(w in line for w in words), (words, line)
    assert not db.exists()


@fuzz(2 * FAST)
@given(data=st.data())
def test_fuzz_forged_archives(genuine, tmp_path_factory, data):
    check_forged(data, genuine, tmp_path_factory.getbasetemp() / "fuzz-forged")


@pytest.mark.slow
@fuzz(SLOW)
@given(data=st.data())
def test_fuzz_forged_archives_more(genuine, tmp_path_factory, data):
    check_forged(data, genuine, tmp_path_factory.getbasetemp() / "fuzz-forged")


def test_the_genuine_archive_imports(genuine: Path, tmp_path: Path):
    """The forgeries start from an archive that imports: their refusals are the forgery's doing."""
    res = runner.invoke(app, ["db", "import", str(genuine), "--db", str(tmp_path / "x.db")])
    assert res.exit_code == 0, res.output
