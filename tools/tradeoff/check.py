"""``--check``: re-run the points of an earlier table and compare time and accuracy."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from tools.tradeoff.report import METRICS, Summary, _cell, _num, parse_markdown, read_csv, summarise

CHECKED = ("time_s", "chamfer", "psnr")
"""Quantities ``--check`` compares (relative tolerance); the others are reported only."""


@dataclass
class CheckResult:
    """One point of ``--check``: reference vs new value per checked quantity."""

    scene: str
    stage: str
    point: str
    ref: dict[str, float]
    new: dict[str, float]
    ok: bool
    failures: list[str]


def compare(ref: dict[str, float], new: dict[str, float], tolerance: float,
            keys: Sequence[str] = CHECKED) -> list[str]:
    """Quantities of ``keys`` whose new value is off the reference by more than ``tolerance``.

    Relative: ``|new / ref − 1| <= tolerance`` passes. A quantity missing (NaN) in the reference
    is not checked; missing in the new run, it fails.
    """
    bad = []
    for k in keys:
        r, n = _num(ref.get(k)), _num(new.get(k))
        if math.isnan(r):
            continue
        if math.isnan(n) or r == 0 and n != 0 or r != 0 and abs(n / r - 1) > tolerance + 1e-12:
            bad.append(k)
    return bad


def check(ref_rows: Sequence[dict], new: Sequence[Summary], tolerance: float) -> list[CheckResult]:
    """Compare a previous table's rows with new summaries of the same (scene, stage, config)."""
    index = {(s.scene, s.stage, s.preset, s.overrides): s for s in new}
    out = []
    for r in ref_rows:
        s = index.get((r["scene"], r["stage"], r["preset"], r["overrides"]))
        refv = {k: _num(r.get(k)) for k in METRICS}
        if s is None:
            out.append(CheckResult(r["scene"], r["stage"], r["point"], refv, {}, False,
                                   ["not re-run"]))
            continue
        bad = compare(refv, s.values, tolerance)
        out.append(CheckResult(r["scene"], r["stage"], r["point"], refv, dict(s.values),
                               not bad, bad))
    return out


def render_check(results: Sequence[CheckResult], tolerance: float) -> str:
    """Markdown report of :func:`check`: reference, new and ratio per checked quantity."""
    head = ["point", "scene", "stage"] + [f"{k} ref → new" for k in CHECKED] + ["verdict"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for c in results:
        cells = [c.point, c.scene, c.stage]
        for k in CHECKED:
            r, n = c.ref.get(k, float("nan")), c.new.get(k, float("nan"))
            ratio = "" if math.isnan(r) or math.isnan(n) or r == 0 else f" ({n / r:.2f}×)"
            cells.append(f"{_cell(k, r)} → {_cell(k, n)}{ratio}")
        cells.append("✔ within" if c.ok else "✘ " + ", ".join(c.failures))
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + f"\n\nTolerance ±{tolerance:.0%} (relative).\n"


def load_reference(path: Path) -> list[dict]:
    """Reference rows for ``--check``: a ``tradeoff.csv`` (medians taken) or a Markdown table."""
    from voxnero.errors import DataError

    if not path.is_file():
        raise DataError("no such table", path=path, fix="pass a tradeoff.md/.csv or a README")
    if path.suffix.lower() == ".csv":
        rows = [{"scene": s.scene, "stage": s.stage, "point": s.point, "preset": s.preset,
                 "overrides": s.overrides, **s.values} for s in summarise(read_csv(path))]
        paths = {r["scene"]: r["scene_path"] for r in read_csv(path)}
        for r in rows:
            r["scene_path"] = paths.get(r["scene"], "")
    else:
        rows = parse_markdown(path.read_text())
    if not rows:
        raise DataError("no trade-off table found", path=path,
                        fix="pass a file holding a table written by python -m tools.tradeoff")
    return rows

