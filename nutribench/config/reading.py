"""Reading a configuration file as data, bounded: what it may be, how large, how deep.

Every config file (a regime, the food catalog, the reward, an agent file, a search space) is
read through :func:`read_config_bytes` and :func:`parse_config`, so that no file a user (or
anyone who can write to a folder of theirs) puts there can hang or crash a command:

* only a regular file is read: a FIFO blocks its reader until someone writes to it, a device
  such as ``/dev/zero`` never ends. The file is opened without blocking and its kind checked on
  the open descriptor, before a byte is read (:func:`read_config_bytes`);
* at most :data:`MAX_CONFIG_BYTES` (its size checked before it is read, and no more read);
* at most :data:`MAX_DEPTH` levels of nesting, counted on the text before ``tomllib`` parses it
  (``tomllib`` recurses two or three frames per level of arrays and inline tables, and spends
  quadratic time on a dotted key's parts: 100,000 levels were a ``RecursionError`` after 16 s,
  a key of 100,000 parts ran out of memory) and again on the parsed data (a table header's
  parts and a dotted key's add up);
* no control character in a string or key but tab and newline (a NUL is stored by no
  database's text column: the archive, and PostgreSQL, refuse it after the run; an escape
  sequence would reach the terminal in every table), and at most :data:`MAX_TEXT` characters
  in each.

Each refusal is one :class:`ConfigError` line naming the file (and the key) and what to do.
"""

from __future__ import annotations

import os
import re
import stat
import tomllib
from pathlib import Path
from typing import Any

from nutribench.errors import UserError
from nutribench.safe_write import file_kind

#: The most bytes a config file may have. Every command reads its config files when it starts
#: (a grid's regimes and agents, a catalog, a reward: about twenty), and ``tomllib`` reads about
#: 0.55 MB/s on a busy two-core machine (measured: a catalog of 10,000 foods, 2.0 MB, took
#: 3.4 s), so a file within the bound parses in under 2 s; the largest committed config file
#: has 2.7 KB (the food catalog), 380 times less. A catalog of 10^5 foods (9.7 MB) is refused
#: before a byte of it is read.
MAX_CONFIG_BYTES = 1 << 20

#: The most levels of nesting in a config file. The committed files nest four (a regime's
#: ``ranges.tau.C.low``). Each level costs its readers a few frames of Python's stack of 1,000:
#: ``tomllib`` two or three (value -> array or inline table -> value), the content hash's
#: ``json.dumps`` and the archive's walks over a stored config one each; 64 levels take at
#: most about 200 frames, above the hundred or so of the command that reads them.
MAX_DEPTH = 64

#: The most characters in one string of a config file (a description, a food's name, a key, a
#: plug-in's parameter). Descriptions are one line of the tables ``regimes list`` and the
#: reports print; the longest committed string has 249 characters. A stated bound, not a
#: derived one: it keeps a 10 MB "description" out of every table and database row.
MAX_TEXT = 4096

#: The control characters refused in a string: C0 (but tab and newline), DEL and C1.
_CONTROL = re.compile(r"[\x00-\x08\x0b-\x1f\x7f-\x9f]")

#: What nests or separates in TOML text, strings and comments whole (they hold no structure).
_TOKENS = re.compile(
    r'"""(?:[^\\]|\\.)*?"""(?!")'  # a multi-line basic string (up to two quotes before its end)
    r"|'''.*?'''(?!')"  # a multi-line literal string
    r'|"(?:[^"\\\n]|\\.)*"'  # a basic string
    r"|'[^'\n]*'"  # a literal string
    r"|#[^\n]*"  # a comment
    r"|[\[\]{}.=,\n]",
    re.S,
)


class ConfigError(UserError, ValueError):
    """A configuration file is missing or invalid. The message is one line for users."""


def read_config_bytes(path: Path | str) -> bytes:
    """The bytes of the config file at ``path``: a regular file (links followed) of at most
    :data:`MAX_CONFIG_BYTES`; a one-line :class:`ConfigError` otherwise (a missing file, a FIFO,
    a device, a folder, one too large), and nothing waits: the file is opened without blocking
    and checked on its open descriptor."""
    path = Path(path)
    try:
        found = os.stat(path)
        if not stat.S_ISREG(found.st_mode):
            raise _not_regular(path, found.st_mode)
        fd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0))
        with os.fdopen(fd, "rb") as fh:  # closed whatever happens
            opened = os.fstat(fd)
            if not stat.S_ISREG(opened.st_mode):  # replaced between the two looks
                raise _not_regular(path, opened.st_mode)
            if opened.st_size > MAX_CONFIG_BYTES:
                raise _too_large(path, opened.st_size)
            data = fh.read(MAX_CONFIG_BYTES + 1)
    except FileNotFoundError:
        raise ConfigError(f"{path}: file not found") from None
    except OSError as e:  # no permission, a loop of links, an I/O error
        raise ConfigError(f"{path}: cannot read the file: {e.strerror or e}") from None
    if len(data) > MAX_CONFIG_BYTES:  # it grew while it was read
        raise _too_large(path, len(data))
    return data


def _not_regular(path: Path, mode: int) -> ConfigError:
    return ConfigError(
        f"{path}: is {file_kind(mode)}, not a regular file: a config file is read only from a "
        "regular file; give the path of one (or move this out of the folder)"
    )


def _too_large(path: Path, size: int) -> ConfigError:
    return ConfigError(
        f"{path}: {size:,} bytes, more than the {MAX_CONFIG_BYTES:,} a config file may have: "
        "it is not a config file nutribench can read quickly; shorten it"
    )


def parse_config(path: Path | str, data: bytes) -> dict[str, Any]:
    """``data`` (the bytes of the file at ``path``) as TOML: UTF-8, nested at most
    :data:`MAX_DEPTH` levels, its strings bounded (:func:`check_strings`); a one-line
    :class:`ConfigError` otherwise (the line of a byte that is not UTF-8, tomllib's own line
    and column for malformed TOML)."""
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as e:
        line = data[: e.start].count(b"\n") + 1
        raise ConfigError(
            f"{path}: line {line}: byte 0x{data[e.start]:02x} is not UTF-8: TOML files are UTF-8, "
            "save the file as UTF-8"
        ) from None
    _check_text_depth(path, text)
    try:
        parsed = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{path}: not valid TOML: {e}") from None
    except RecursionError:  # nesting the text scan did not see: never a traceback
        raise _too_deep(path, "its arrays and tables") from None
    check_strings(path, parsed)
    return parsed


def _too_deep(path: Path | str, what: str, line: int | None = None) -> ConfigError:
    where = f"line {line}: " if line is not None else ""
    return ConfigError(
        f"{path}: {where}{what} nest more than {MAX_DEPTH} levels deep, more than a config file may: flatten them"
    )


def _check_text_depth(path: Path | str, text: str) -> None:
    """Refuse TOML text whose arrays and inline tables nest, or whose dotted keys have parts,
    more than :data:`MAX_DEPTH` deep, before it is parsed (strings and comments skipped)."""
    depth = dots = 0
    for m in _TOKENS.finditer(text):
        tok = m.group()
        if tok == ".":
            dots += 1
        elif tok in "[]{}=,\n":  # what ends a dotted key (strings and comments are longer tokens)
            dots = 0
        if tok in "[{":
            depth += 1
        elif tok in "]}":
            depth = max(depth - 1, 0)
        if depth > MAX_DEPTH or dots >= MAX_DEPTH:  # only one at a time: an opening bracket ends a dotted key
            what = "its arrays and tables" if depth > MAX_DEPTH else "the parts of a dotted key"
            raise _too_deep(path, what, text.count("\n", 0, m.start()) + 1)


def check_strings(path: Path | str, data: Any) -> None:
    """Refuse parsed config ``data`` nested more than :data:`MAX_DEPTH` levels, or holding a
    string or key with a control character (but tab and newline) or of more than
    :data:`MAX_TEXT` characters; the one line names the key (``food[3].name``)."""
    stack: list[tuple[Any, str, int]] = [(data, "", 0)]
    while stack:
        value, where, depth = stack.pop()
        if depth > MAX_DEPTH:
            raise _too_deep(path, f"{_short(where)}: its tables")
        if isinstance(value, dict):
            for key, item in value.items():
                name = f"{where}.{key}" if where else str(key)
                _check_text(path, name, key, "key")
                stack.append((item, name, depth + 1))
        elif isinstance(value, list):
            stack.extend((item, f"{where}[{n}]", depth + 1) for n, item in enumerate(value))
        elif isinstance(value, str):
            _check_text(path, where, value, "value")


def _check_text(path: Path | str, where: str, text: str, what: str) -> None:
    if len(text) > MAX_TEXT:
        raise ConfigError(
            f"{path}: {_short(where)}: its {what} has {len(text):,} characters, more than the "
            f"{MAX_TEXT:,} a config file's string may have: shorten it"
        )
    bad = _CONTROL.search(text)
    if bad:
        char = bad.group()
        name = " (a NUL)" if char == "\x00" else ""
        raise ConfigError(
            f"{path}: {_short(where)}: its {what} holds the control character U+{ord(char):04X}{name} "
            f"at character {bad.start()}, which no config text may hold (a database stores no NUL; "
            "a terminal acts on the others): remove it"
        )


def _short(where: str) -> str:
    """A key's path as the line shows it: escaped (a key may hold anything), at most 80 characters."""
    shown = where.encode("unicode_escape").decode("ascii")
    return shown if len(shown) <= 80 else f"{shown[:60]}...({len(shown):,} characters)"
