"""The command line's stop signals: Ctrl-C (SIGINT), a batch system's preemption (SIGTERM) and
a closed terminal (SIGHUP) all end a ``nutribench run`` in the same graceful stop (running jobs
released as ``interrupted``, exit 130), however many of them arrive.

Signal handlers belong to the program, not to a library: :func:`nutribench.scheduler.driver.run_grid`
installs none (it stops on KeyboardInterrupt, or when its ``stop`` event is set), so a
notebook or a script that calls it keeps its own handlers; the ``run`` command installs these
around its call.
"""

from __future__ import annotations

import signal
import threading
import time
from typing import Any

#: Signals that stop a run as Ctrl-C does: a batch system's preemption (SIGTERM) and a closed
#: terminal (SIGHUP) release the running jobs as ``interrupted`` at once.
STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)


class StopSignalsAsCtrlC:
    """Within the block (main thread only), the first stop signal raises KeyboardInterrupt;
    later ones are ignored: in the block for a second (then the first counts as lost), and
    after a stop until the process exits (the command is ending: a second Ctrl-C must not
    break its last lines). Without a stop, the handlers found are put back. SIGINT stays
    ignored where it was (a shell's background job)."""

    def __enter__(self) -> None:
        self.previous, self.raised_at = {}, None
        # only the main thread may install signal handlers
        for sig in STOP_SIGNALS if threading.current_thread() is threading.main_thread() else ():
            if sig != signal.SIGINT or signal.getsignal(sig) is not signal.SIG_IGN:
                self.previous[sig] = signal.signal(sig, self._stop)

    def _stop(self, signum: int, frame: Any) -> None:
        if self.raised_at is None or time.monotonic() - self.raised_at > 1.0:
            self.raised_at = time.monotonic()
            raise KeyboardInterrupt(signal.Signals(signum).name)

    def __exit__(self, kind: type[BaseException] | None, *exc: object) -> None:
        stopped = self.raised_at is not None or (kind is not None and issubclass(kind, KeyboardInterrupt))
        for sig, handler in self.previous.items():
            signal.signal(sig, signal.SIG_IGN if stopped else handler)
