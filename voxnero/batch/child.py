"""The process that runs one scene's stage commands (``python -m voxnero.batch.child SPEC``).

A scene's Ray task starts this process and waits for it, so that

* the stages run in-process through :func:`voxnero.cli.build_parser` (one Python start and
  one import of torch/Open3D per scene, not per stage);
* the task measures the scene's own peak memory (``os.wait4`` of this process);
* killing the Ray worker loses at most the work since the last checkpoint: on Linux this process
  asks the kernel for SIGTERM when its parent dies (``PR_SET_PDEATHSIG``), and SIGTERM makes a
  stage save a checkpoint and stop (``voxnero shape`` saves at the end of the current step);
  the retried task waits for this process to stop (it holds the scene's lock) before resuming.

``SPEC`` is a JSON file ``{"stages": [{"name": ..., "argv": [...]}, ...], "status": PATH}``;
after each stage ``PATH`` gets ``{"stages": [{"name", "rc", "time_s", "error"}, ...]}``.
Exit code: 0 all stages done, 2 a stage failed (its ``error`` says why), 130 interrupted.
"""

from __future__ import annotations

import json
import os
import signal
import sys
import time
import traceback
from pathlib import Path

PARENT_ENV = "VOXNERO_BATCH_PARENT"
"""Environment variable holding the PID of the task process that started this one."""


def _die_with_parent() -> None:
    """SIGTERM this process when the task process dies (Linux; elsewhere a no-op)."""
    parent = os.environ.get(PARENT_ENV)
    if not sys.platform.startswith("linux") or not parent:
        return
    import ctypes

    pr_set_pdeathsig = 1
    try:
        ctypes.CDLL(None, use_errno=True).prctl(pr_set_pdeathsig, int(signal.SIGTERM), 0, 0, 0)
    except (OSError, AttributeError):
        return
    if os.getppid() != int(parent):  # the parent died before prctl took effect
        raise KeyboardInterrupt


def _sigterm(signum, frame) -> None:
    raise KeyboardInterrupt


def run_stage(argv: list[str]) -> tuple[int, str]:
    """Run one ``voxnero`` command in this process.

    Returns:
        ``(rc, error)``: 0 and "" on success; 2 and a one-line reason otherwise (user errors
        give their message, crashes the exception's last line, the traceback goes to stdout).

    Raises:
        KeyboardInterrupt: the stage was interrupted (SIGTERM/SIGINT); checkpoints are kept.
    """
    from voxnero.cli import build_parser, parse_command_line
    from voxnero.errors import VoxneroError

    try:
        args = parse_command_line(build_parser(), argv)
        rc = int(args._run(args) or 0)
        return rc, "" if rc == 0 else f"exit code {rc}"
    except VoxneroError as e:
        return 2, " ".join(str(e).split())
    except SystemExit as e:  # argparse: bad arguments (the message is already printed)
        return (2, f"bad arguments to voxnero {argv[0]} (see batch.log)") if e.code else (0, "")
    except KeyboardInterrupt:
        raise
    except Exception as e:  # noqa: BLE001 - a crash of one scene is reported, not fatal
        traceback.print_exc(file=sys.stdout)
        return 2, f"{type(e).__name__}: {e}".splitlines()[0][:300]


def main(argv: list[str] | None = None) -> int:
    """Run the stages of the spec file ``argv[0]``; returns the exit code."""
    argv = sys.argv[1:] if argv is None else argv
    spec = json.loads(Path(argv[0]).read_text())
    status_path = Path(spec["status"])
    done: list[dict] = []

    def write_status() -> None:
        tmp = status_path.with_suffix(".tmp")
        tmp.write_text(json.dumps({"stages": done}, indent=1))
        os.replace(tmp, status_path)

    signal.signal(signal.SIGTERM, _sigterm)
    try:
        _die_with_parent()
        for stage in spec["stages"]:
            t0 = time.perf_counter()
            print(f"[batch] {stage['name']}: voxnero {' '.join(stage['argv'])}", flush=True)
            rc, err = run_stage(stage["argv"])
            dt = time.perf_counter() - t0
            done.append({"name": stage["name"], "rc": rc, "time_s": round(dt, 2), "error": err})
            write_status()
            print(f"[batch] {stage['name']}: {'done' if rc == 0 else 'FAILED: ' + err} "
                  f"in {dt:.1f} s", flush=True)
            if rc:
                return 2
    except KeyboardInterrupt:
        print("[batch] interrupted; checkpoints are kept, a retry resumes from them", flush=True)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
