"""Ctrl-C (SIGINT) and ``kill`` (SIGTERM) stop a training loop between two steps.

A signal lands anywhere, often inside a step (half an optimiser update, random numbers drawn);
a checkpoint taken there would not resume to the run that was not interrupted. So the handler
only sets a flag; the loop checks it after each complete step, saves a checkpoint and raises
:class:`KeyboardInterrupt`. A second signal before that stops at once (``forced``): the loop
then saves nothing and the last checkpoint stays. A SIGTERM that repeats a SIGTERM within
:data:`REPEAT_S` is the same request, not a second one: a supervisor that dies often sends two
(``voxnero batch``'s stage process gets the kernel's ``PR_SET_PDEATHSIG`` SIGTERM and Ray's own
when a worker is killed), and the step would otherwise be cut short with no checkpoint.
"""

from __future__ import annotations

import signal
import time
from typing import Any

SIGNALS = (signal.SIGINT, signal.SIGTERM)
REPEAT_S = 2.0
"""Seconds within which a repeated SIGTERM counts as the first one (Ctrl-C twice still forces)."""


class GracefulStop:
    """Context manager turning SIGINT/SIGTERM into a flag for the duration of a loop.

    Attributes:
        flag: a signal arrived; stop after the current step.
        forced: a second signal arrived and interrupted the step (do not checkpoint).
        signum: the first signal's number.
    """

    def __init__(self) -> None:
        self.flag = False
        self.forced = False
        self.signum: int | None = None
        self._first_at = 0.0
        self._old: dict[int, Any] = {}

    def __enter__(self) -> GracefulStop:
        for s in SIGNALS:
            try:
                self._old[s] = signal.signal(s, self._handler)
            except ValueError:  # not the main thread: signals stay as they are
                break
        return self

    def _handler(self, signum: int, frame: Any) -> None:
        now = time.monotonic()
        if self.flag:
            if (signum == self.signum == signal.SIGTERM
                    and now - self._first_at < REPEAT_S):
                return  # the same stop request, sent twice
            self.forced = True
            raise KeyboardInterrupt
        self.flag, self.signum, self._first_at = True, signum, now

    def __exit__(self, *exc: Any) -> None:
        for s, old in self._old.items():
            signal.signal(s, old if old is not None else signal.SIG_DFL)
        self._old.clear()
