"""Non-finite guard of the training loops.

A step whose loss (or gradient) is NaN/Inf is skipped: one bad batch must not poison the
parameters. A loss that *stays* non-finite is not a bad batch but a bad setting or bad data;
:class:`NonFiniteGuard` stops such a run after :data:`MAX_NONFINITE_STEPS` consecutive skipped
steps with a :class:`~voxnero.errors.TrainingError` naming the likely cause, instead of writing
the untrained model as a result. :func:`check_finite` refuses to checkpoint NaN/Inf state.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from pathlib import Path

import torch

from voxnero.errors import TrainingError

MAX_NONFINITE_STEPS = 20
"""Consecutive non-finite steps after which a run stops. Isolated bad batches (a saturated exp
in a few rays) have been seen one at a time; twenty in a row have always been a setting or the
data."""


class NonFiniteGuard:
    """Counts consecutive non-finite steps of a loop.

    Args:
        stage: command name for messages (``shape``).
        cause: called when the run stops; returns the likely cause as a phrase.
        fix: what to change, for the message.
        limit: consecutive non-finite steps that stop the run.
    """

    def __init__(self, stage: str, cause: Callable[[], str], fix: str,
                 limit: int = MAX_NONFINITE_STEPS):
        self.stage, self.cause, self.fix, self.limit = stage, cause, fix, limit
        self.streak = 0
        self.first = -1
        self.steps = 0
        """Steps seen by this guard (finite or not)."""

    def update(self, finite: bool, step: int, last: bool = False) -> None:
        """Record one step (``step`` = its index); ``last``: the loop ends with it.

        Raises:
            TrainingError: ``limit`` consecutive non-finite steps, or every step of the loop
                was non-finite when it ends.
        """
        self.steps += 1
        if finite:
            self.streak = 0
            return
        if self.streak == 0:
            self.first = step
        self.streak += 1
        if self.streak >= self.limit or (last and self.streak == self.steps):
            raise TrainingError(
                f"the loss was non-finite (NaN/Inf) for {self.streak} consecutive steps "
                f"({self.first}-{step}); likely cause: {self.cause()}. Nothing was written "
                "after the last good checkpoint", fix=self.fix)


def nonfinite(named: Iterable[tuple[str, torch.Tensor]]) -> list[str]:
    """Names of the tensors holding NaN/Inf."""
    return [n for n, t in named if t.is_floating_point() and not bool(torch.isfinite(t).all())]


def check_finite(named: Iterable[tuple[str, torch.Tensor]], path: str | Path,
                 fix: str) -> None:
    """Refuse to checkpoint state holding NaN/Inf.

    Args:
        named: ``(name, tensor)`` pairs (``module.named_parameters()``).
        path: the checkpoint that would have been written (named in the error; left as it was).
        fix: what to change.

    Raises:
        TrainingError: naming the first tensors that hold NaN/Inf.
    """
    bad = nonfinite(named)
    if bad:
        raise TrainingError(f"not saved: the model holds NaN/Inf in {', '.join(bad[:4])}"
                            f"{' ...' if len(bad) > 4 else ''}; the file keeps the last good "
                            "state", path=path, fix=fix)
