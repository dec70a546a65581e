"""The one base class of the errors a user can fix.

Every room raises its own subclass (``ConfigError`` for config files, ``StoreError`` for
databases, ``GridError`` for grid options, ``ExecutorError`` for ``--executor``,
``RunError`` for a run, ``ReportError`` for a report); the CLI turns any ``UserError``
into one red line and exit status 2 (:func:`nutribench.cli.common.user_errors`). Anything
else is a bug and keeps its traceback. This module sits at the bottom of the house and
imports nothing from nutribench.
"""

from __future__ import annotations


class UserError(Exception):
    """An error the user can fix. Its message is one line: what, where, how to fix."""


def check_range(option: str, value: int, low: int, high: int, why: str = "") -> None:
    """``option value`` within ``low..high``, else a one-line UserError (``why``: the reason for ``high``)."""
    if not low <= value <= high:
        raise UserError(f"{option} {str(value)[:24]}: give a value from {low} to {high}" + (f" ({why})" if why else ""))
