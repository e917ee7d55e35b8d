"""The batch's result table: ``results.csv`` (machine-readable) and ``results.md`` (to read).

One row per scene, in manifest order, as returned by :func:`voxnero.batch.tasks.run_scene`
(or made by the driver for a scene that failed before or outside its task).
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import Any

from voxnero.safety.folder import atomic_write_text

COLUMNS = ["scene", "status", "error", "time_s", "peak_mem_mb", "attempts", "chamfer",
           "normal_deg", "psnr", "mesh", "model", "metrics", "out", "path"]
"""Columns of ``results.csv`` (``time_s``: wall seconds of the last attempt; ``peak_mem_mb``:
max RSS of the scene's stage process in MiB; ``attempts``: task attempts over all runs of the
batch (Ray retries included); ``chamfer``: NeRO-protocol Chamfer distance in the
normalised frame; ``normal_deg``: mean normal error in degrees; ``psnr``: novel-view PSNR in dB
of stage 2; empty where the scene has no ground truth or the stage did not run)."""


def _cell(v: Any) -> str:
    if v is None:
        return ""
    if isinstance(v, float):
        return "" if math.isnan(v) else f"{v:.6g}"
    return str(v)


def summarize(rows: list[dict[str, Any]]) -> dict[str, int]:
    """Counts of rows per status (``ok``, ``skipped``, ``error``) and in total."""
    out = {"ok": 0, "skipped": 0, "error": 0}
    for r in rows:
        out[r.get("status", "error")] = out.get(r.get("status", "error"), 0) + 1
    out["total"] = len(rows)
    return out


def all_succeeded(rows: list[dict[str, Any]]) -> bool:
    """Whether every scene is finished (``ok`` now or ``skipped`` as finished earlier)."""
    return all(r.get("status") in ("ok", "skipped") for r in rows)


def write_csv(path: str | Path, rows: Iterable[dict[str, Any]],
              columns: Sequence[str] = COLUMNS, cell: Callable[[Any], str] = _cell) -> Path:
    """Write ``rows`` with ``columns`` (extra keys are left out), atomically.

    Each value (None where a row lacks the column) is written as ``cell(value)``; the default
    leaves None and NaN empty and writes floats with 6 significant digits.
    """
    path = Path(path)
    buf = io.StringIO(newline="")
    w = csv.writer(buf)
    w.writerow(columns)
    for r in rows:
        w.writerow([cell(r.get(c)) for c in columns])
    return atomic_write_text(path, buf.getvalue())


def _md(v: Any, digits: int) -> str:
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "—"
    if isinstance(v, float):
        return f"{v:.{digits}f}"
    return str(v).replace("|", "\\|").replace("\n", " ")


def write_markdown(path: str | Path, rows: list[dict[str, Any]], title: str = "VoxNeRO batch"
                   ) -> Path:
    """Write a Markdown report: a summary line, the per-scene table, then the errors in full."""
    path = Path(path)
    s = summarize(rows)
    lines = [f"# {title}", "",
             f"{s['total']} scenes: {s['ok']} done now, {s['skipped']} finished earlier "
             f"(skipped), {s['error']} failed.", "",
             "| scene | status | time (s) | peak mem (MiB) | attempts | Chamfer | normal err (°) "
             "| PSNR (dB) | outputs |",
             "|---|---|---:|---:|---:|---:|---:|---:|---|"]
    for r in rows:
        outs = ", ".join(f"[{Path(r[k]).name}]({r[k]})" for k in ("mesh", "model", "metrics")
                         if r.get(k))
        lines.append(f"| {_md(r.get('scene'), 0)} | {_md(r.get('status'), 0)} | "
                     f"{_md(r.get('time_s'), 1)} | {_md(r.get('peak_mem_mb'), 0)} | "
                     f"{_md(r.get('attempts'), 0)} | {_md(r.get('chamfer'), 4)} | "
                     f"{_md(r.get('normal_deg'), 1)} | {_md(r.get('psnr'), 2)} | {outs or '—'} |")
    errors = [r for r in rows if r.get("status") == "error"]
    if errors:
        lines += ["", "## Errors", ""]
        lines += [f"- **{_md(r.get('scene'), 0)}** ({r.get('path')}): {_md(r.get('error'), 0)}"
                  for r in errors]
    lines += ["", "Chamfer: NeRO protocol, normalised frame; PSNR: stage-2 novel views; time: "
              "wall seconds of the last attempt; peak mem: max RSS of the scene's process."]
    atomic_write_text(path, "\n".join(lines) + "\n")
    return path


def write_results(out: str | Path, rows: list[dict[str, Any]]) -> tuple[Path, Path]:
    """Write ``results.csv`` and ``results.md`` into ``out``; returns both paths."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    return write_csv(out / "results.csv", rows), write_markdown(out / "results.md", rows)
