"""A command as a measured child process: exit code, wall time (s), peak RSS (MiB).

Two ways, one measurement (:func:`wait_measured`, ``os.wait4``):

* :func:`voxnero.batch.tasks.run_scene` waits for its stage process directly, because that
  process must be the task's own child (``PR_SET_PDEATHSIG`` ties it to the task, it inherits
  the scene's lock, a retry finds it by its parent);
* :func:`run_timed` (``tools/tradeoff``) runs the command under a launcher
  (``python -m voxnero.batch.process RESULT CMD ...``), in its own session, with a timeout,
  and kills its whole process group on timeout or Ctrl-C.

Why the launcher: Python starts children with ``vfork`` (or ``fork``), and Linux carries the
parent's resident-set high-water mark over into the child's ``ru_maxrss`` across the ``exec``;
a sweep started from a process holding torch (a test, a notebook) would report that process's
RSS for every small child. Started from the launcher, the floor is the launcher's own ~10 MiB
(this module imports the standard library only).
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path


@dataclass
class ChildResult:
    """What one subprocess cost: exit code, wall time (s), peak RSS (MiB)."""

    rc: int
    wall_s: float
    peak_rss_mib: float


def wait_measured(proc: subprocess.Popen) -> tuple[int, float]:
    """Wait for ``proc`` with ``os.wait4``; set its ``returncode``.

    Returns:
        exit code (``-signal`` if killed) and peak RSS in MiB (``ru_maxrss``: the largest
        resident set of the process or of a descendant it waited for).
    """
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    kib = usage.ru_maxrss / (1024.0 if sys.platform == "darwin" else 1.0)  # macOS: bytes
    return proc.returncode, kib / 1024.0


_LIVE: set[int] = set()
"""Process groups of the :func:`run_timed` children running now."""
_LIVE_LOCK = threading.Lock()


def kill_children() -> None:
    """SIGKILL every running :func:`run_timed` child's process group (they run in their own
    sessions, so a Ctrl-C at the terminal does not reach them)."""
    with _LIVE_LOCK:
        for pgid in list(_LIVE):
            try:
                os.killpg(pgid, signal.SIGKILL)
            except ProcessLookupError:
                pass


def read_json(path: Path) -> dict:
    """A JSON file's object, or {} when it is missing or unreadable (a child that died before
    writing it): the one tolerant reader of run files (batch, tools/tradeoff, tools/corpus)."""
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return {}


def run_timed(cmd: Sequence[str], log: Path, timeout: float | None = None,
              env: Mapping[str, str] | None = None, cwd: str | Path | None = None
              ) -> ChildResult:
    """Run ``cmd`` under the launcher, stdout + stderr into ``log``; time it, read its peak RSS.

    ``log`` starts with ``$ CMD``; the launcher writes ``LOG.result.json``. The command runs in
    its own session (process group): a timeout or an exception here (Ctrl-C) kills the group,
    and :func:`kill_children` kills it from another thread.

    Returns:
        exit code (``-signal`` if killed; 124 after ``timeout`` seconds), wall seconds, MiB
        (NaN when the launcher did not report).
    """
    log.parent.mkdir(parents=True, exist_ok=True)
    res = log.with_name(log.name + ".result.json")
    res.unlink(missing_ok=True)
    with open(log, "wb") as fh:
        fh.write(("$ " + " ".join(cmd) + "\n").encode())
        fh.flush()
        t0 = time.perf_counter()
        proc = subprocess.Popen([sys.executable, "-m", "voxnero.batch.process", str(res), *cmd],
                                stdout=fh, stderr=subprocess.STDOUT,
                                env=dict(env) if env is not None else None, cwd=cwd,
                                start_new_session=True)
        with _LIVE_LOCK:
            _LIVE.add(proc.pid)
        try:
            proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)  # the launcher and the command
            proc.wait()
            return ChildResult(124, time.perf_counter() - t0, float("nan"))
        except BaseException:  # Ctrl-C: do not leave the command running on its own
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
            raise
        finally:
            with _LIVE_LOCK:
                _LIVE.discard(proc.pid)
    info = read_json(res)
    if not info:
        return ChildResult(proc.returncode or 1, time.perf_counter() - t0, float("nan"))
    return ChildResult(int(info["rc"]), float(info["wall_s"]), float(info["peak_rss_mib"]))


def _launch(argv: Sequence[str]) -> int:
    """The launcher: run ``argv[1:]``, write ``{"rc", "wall_s", "peak_rss_mib"}`` to ``argv[0]``."""
    t0 = time.perf_counter()
    rc, mib = wait_measured(subprocess.Popen(list(argv[1:])))
    wall = time.perf_counter() - t0
    Path(argv[0]).write_text(json.dumps({"rc": rc, "wall_s": wall, "peak_rss_mib": mib}))
    return 0


if __name__ == "__main__":
    sys.exit(_launch(sys.argv[1:]))
