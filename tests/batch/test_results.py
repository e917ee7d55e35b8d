"""results.csv / results.md: columns, number formatting, summary and exit status."""

from __future__ import annotations

import csv
import math

from voxnero.batch.results import (
    COLUMNS,
    all_succeeded,
    summarize,
    write_results,
)

ROWS = [
    {"scene": "a", "status": "ok", "error": "", "time_s": 12.345678, "peak_mem_mb": 470.0,
     "attempts": 2, "chamfer": 0.0123456789, "normal_deg": 3.5, "psnr": 25.25,
     "mesh": "/o/a/shape/mesh.ply", "model": "/o/a/material/model.glb", "metrics": None,
     "out": "/o/a", "path": "/s/a", "extra": "not a column"},
    {"scene": "b|c", "status": "skipped", "time_s": 1.0, "chamfer": float("nan")},
    {"scene": "d", "status": "error", "error": "reconstruct: bad\nthing", "path": "/s/d"},
]


def test_csv_round_trip(tmp_path):
    csv_path, _ = write_results(tmp_path, ROWS)
    with open(csv_path, newline="") as fh:
        got = list(csv.DictReader(fh))
    assert list(got[0]) == COLUMNS and len(got) == 3
    assert math.isclose(float(got[0]["chamfer"]), 0.0123456789, rel_tol=1e-5)
    assert got[0]["attempts"] == "2" and got[0]["metrics"] == ""
    assert got[1]["chamfer"] == "" and got[1]["scene"] == "b|c"
    assert got[2]["error"] == "reconstruct: bad\nthing"


def test_markdown_table_and_errors(tmp_path):
    _, md_path = write_results(tmp_path, ROWS)
    md = md_path.read_text()
    table = [ln for ln in md.splitlines() if ln.startswith("| ")][1:]
    assert len(table) == 3
    assert table[0].count(" | ") == 8  # 9 columns, the escaped "|" of b|c does not count
    assert "b\\|c" in table[1] and "0.0123" in table[0] and "25.25" in table[0]
    assert "3 scenes: 1 done now, 1 finished earlier (skipped), 1 failed." in md
    assert "- **d** (/s/d): reconstruct: bad thing" in md


def test_summary_and_success():
    assert summarize(ROWS) == {"ok": 1, "skipped": 1, "error": 1, "total": 3}
    assert not all_succeeded(ROWS)
    assert all_succeeded(ROWS[:2]) and all_succeeded([])
