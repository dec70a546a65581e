"""What every command module of the CLI shares: the consoles, the one-line error
decorator, the parsing of comma lists and the progress line of the long commands.

Errors a user can fix derive from :class:`nutribench.errors.UserError` in whichever room
raises them; :func:`user_errors` prints them as one red line and exits with status 2.
Anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

import errno
import functools
import re
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Annotated, Any, Optional

import typer
from rich.console import Console
from rich.markup import escape

from nutribench.errors import UserError

#: the help of ``--device`` (checked by :mod:`nutribench.engine.device`, which imports torch: not here)
DEVICE_HELP = "where the batched engine trains: 'auto' (CUDA when available, else the CPU), 'cpu', 'cuda' or 'cuda:N'"

EVAL_EVERY_HELP = (
    "every so many training days, the greedy policy plays the validation days (evaluation during "
    "training, disjoint from the test days; 0: never, the default)"
)


def option(kind: Any, help: str | None, *names: str, **settings: Any) -> Any:
    """A command's option as its parameter's annotation, in one line: ``Annotated[kind,
    typer.Option(*names, help=help, **settings)]`` (``names``: its flags, where the parameter's
    name does not give them; typer reads the ``Annotated`` metadata)."""
    return Annotated[kind, typer.Option(*names, help=help, **settings)]


def path_flag(flag: str, help: str) -> Any:
    """A path option ``flag PATH``, declared as an optional ``str`` (None: not given) and read
    through :func:`path_option` or :func:`folder_option`."""
    return option(Optional[str], help, flag, metavar="PATH")


def argument(kind: Any, help: str, **settings: Any) -> Any:
    """A command's argument as its parameter's annotation (:func:`option`'s, for ``typer.Argument``)."""
    return Annotated[kind, typer.Argument(help=help, **settings)]


#: the options several commands share, written once
DbOption = option(str, "results database: a SQLite file or a SQLAlchemy URL", envvar="NUTRIBENCH_DB")
#: ``--episodes``, the old spelling of ``--days`` (hidden; :func:`old_spelling` reconciles the two)
EpisodesAlias = Annotated[Optional[int], typer.Option("--episodes", min=1, hidden=True)]
ValEpisodesOption = option(int, "validation days each evaluation during training plays", min=1)
MarkdownOption = option(bool, "print a Markdown table", "--markdown")
RepeatsOption = option(int, "timed repeats; the median is reported", min=1)
EvalDaysOption = option(int, "greedy evaluation days per trained agent", min=1)
WorkersOption = option(Optional[int], "agents trained at once (default: the cores)", min=1)
#: ``--reps`` of the commands whose intervals once drew resamples (each with its old default)
KeptRepsOption = option(int, "kept for scripts (100 to 100,000): the intervals draw no resamples now")

console = Console()
err_console = Console(stderr=True)


def command_group(help: str, **options) -> typer.Typer:
    """A group of subcommands (``nutribench NAME ...``): help on no arguments unless ``options``
    say otherwise, no rich markup in its texts."""
    return typer.Typer(rich_markup_mode=None, help=help, **{"no_args_is_help": True, **options})


def say(text: str, **options) -> None:
    """One line on stdout as written (no rich highlighting, no wrapping; ``options``: rich's,
    e.g. ``style``): a library's ``say``."""
    console.print(text, highlight=False, soft_wrap=True, **options)


def say_err(text: str, **options) -> None:
    """One line on stderr as written (:func:`say`'s): what is not the command's output."""
    err_console.print(text, highlight=False, soft_wrap=True, **options)


#: control characters (C0, DEL, C1): a value echoed in an error line shows them escaped
_CONTROL = re.compile(r"[\x00-\x1f\x7f-\x9f]")


def print_error(e: BaseException | str) -> None:
    """One red ``error:`` line on stderr; the message is printed as is (no rich markup), but
    for the secrets of any URL in it (:func:`nutribench.store.engine.hide_secrets`: a message
    that formats a ``--db`` URL as given still shows no password) and its control characters,
    written as escapes (``\\x1b``, ``\\n``): a value the user gave, echoed back, neither acts on
    the terminal nor breaks the one line."""
    text = str(e)
    if "://" in text:
        from nutribench.store.engine import hide_secrets_in

        text = hide_secrets_in(text)
    text = _CONTROL.sub(lambda m: m.group().encode("unicode_escape").decode("ascii"), text)
    err_console.print(f"[bold red]error:[/] {escape(text)}", highlight=False, soft_wrap=True)


def print_table(
    headers: Sequence[str], cells: list[list[str]], title: str | None = None, markdown: bool = False, groups=None
) -> None:
    """A table on stdout: Markdown (``| a | b |`` lines), or a rich one with ``title`` and a
    rule between rows of different ``groups`` (a value per row, e.g. the regime)."""
    if markdown:
        typer.echo("| " + " | ".join(headers) + " |")
        typer.echo("|" + "---|" * len(headers))
        for c in cells:
            typer.echo("| " + " | ".join(c) + " |")
        return
    from rich.table import Table

    table = Table(*headers, title=title)
    for i, c in enumerate(cells):
        table.add_row(*c, end_section=groups is not None and (i + 1 == len(cells) or groups[i + 1] != groups[i]))
    console.print(table)


def path_option(value: str | None, option: str, give: str = "a path") -> Path | None:
    """A path option's value as a path (None: not given); an empty or blank one is a one-line
    :class:`UserError` (``option is empty: give ...``), as ``--db ''`` is: ``Path('')`` is the
    current folder, which an empty value never means. Path options are declared as ``str`` and
    read through this, since typer turns ``''`` into ``Path('.')`` before the command sees it."""
    if value is None:
        return None
    if not value.strip():
        raise UserError(f"{option} is empty: give {give}")
    return Path(value)


def folder_option(value: str | None, option: str) -> Path | None:
    """A folder option's value as a path (None: not given); an empty one is a one-line
    :class:`UserError` (:func:`path_option`; give ``.`` for the current folder)."""
    return path_option(value, option, "a folder ('.' for the current one)")


#: errors of the operating system that only ever mean a path the user gave cannot be one
PATH_ERRNOS = (errno.ENAMETOOLONG, errno.ELOOP)


def user_errors(fn):
    """Any :class:`UserError` raised by the command -> one line on stderr and exit status 2; so is
    an OSError that can only mean a bad path (a name too long, a loop of symbolic links), met
    by whichever check looked at the path first."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except UserError as e:
            print_error(e)
            raise typer.Exit(2) from None
        except OSError as e:
            if e.errno not in PATH_ERRNOS:
                raise
            name = str(e.filename or "")
            shown = name if len(name) <= 80 else f"{name[:60]}...({len(name)} characters)"
            print_error(f"{shown}: {e.strerror}: give another path")
            raise typer.Exit(2) from None

    return wrapper


def split_csv(value: str, known: list[str], what: str, where: str = "") -> list[str]:
    """``"all"`` or a comma-separated subset of ``known``; unknown names are a UserError (its
    line ends with ``where``: where the names come from, how to add one)."""
    if value.strip() == "all":
        return list(known)
    items = [v.strip() for v in value.split(",") if v.strip()]
    if not items:
        raise UserError(f"no {what} given: pass 'all' or a comma-separated list of {', '.join(known)}")
    unknown = [v for v in items if v not in known]
    if unknown:
        raise UserError(
            f"unknown {what} {', '.join(unknown)}: known are {', '.join(known)}{' ' + where if where else ''}"
        )
    return items


def old_spelling(value, old, option: str, old_option: str, default=None):
    """An option given under its name or under its old spelling (a hidden alias that still
    works: ``--episodes`` for ``--days``); both with different values is one line."""
    if value is not None and old is not None and value != old:
        raise UserError(
            f"{option} {value} and {old_option} {old}: give one ({old_option} is the old spelling of {option})"
        )
    return value if value is not None else old if old is not None else default


@contextmanager
def progress(
    total: int | None, description: str, *, text: str = "", lines: bool = False, console: Console | None = None
) -> Iterator[Callable[..., None]]:
    """What a long command is doing, on stderr, while the block runs; yields ``advance(text,
    done=None, total=None)``: the step now under way (``done``: steps finished, default one
    more than before; ``total``: the steps there are, where it becomes known).

    On a terminal: one rich line (a spinner, ``description: text``, a bar of ``done`` of
    ``total`` where a total is known, the time elapsed), gone when the block ends. Where
    stderr is no terminal (a file, a pipe, a test's runner) nothing is shown, or with
    ``lines`` one plain dim line per step: ``text (12 s)``. Stdout is never touched."""
    out = console or err_console
    t0 = time.monotonic()
    if not out.is_terminal:

        def plain(step: str, done: int | None = None, total: int | None = None) -> None:
            if lines:
                out.print(f"{step} ({time.monotonic() - t0:.0f} s)", style="dim", highlight=False, soft_wrap=True)

        yield plain
        return
    from rich.progress import BarColumn, Progress, SpinnerColumn, TextColumn, TimeElapsedColumn
    from rich.table import Column

    bar = Progress(
        SpinnerColumn(),
        TextColumn("{task.description}", table_column=Column(ratio=1, no_wrap=True, overflow="ellipsis")),
        BarColumn(bar_width=16),  # the text is cut on a narrow terminal, never the bar or the time
        TimeElapsedColumn(),
        console=out,
        expand=True,
        transient=True,
        redirect_stdout=False,  # the results printed meanwhile stay on stdout
        redirect_stderr=False,
    )
    task = bar.add_task(f"{description}: {text}" if text else description, total=total)

    def advance(step: str, done: int | None = None, total: int | None = None) -> None:
        finished = bar.tasks[0].completed + 1 if done is None else done
        bar.update(task, description=f"{description}: {step}", completed=finished, total=total)  # None: kept
        bar.refresh()  # each step is shown, however quickly the next one comes

    with bar:
        yield advance
