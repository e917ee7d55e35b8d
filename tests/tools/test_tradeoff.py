"""Tests of ``tools/tradeoff/``: writers, resume, ``--check``, README markers, one real run."""

from __future__ import annotations

import csv
import math
import statistics
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import tools.tradeoff as T

REPO = Path(__file__).resolve().parents[2]

TINY = ("preview shape.iters=20 shape.grid.res=[16,24] shape.mesh_res=48 "
        "shape.sampling.rays=512")


def _row(scene, point, preset, ov, repeat, time_s, chamfer, psnr=float("nan"), stage="shape",
         status="ok", jobs=1):
    return {"scene": scene, "scene_path": f"/data/{scene}", "point": point, "preset": preset,
            "overrides": ov, "stage": stage, "repeat": repeat, "status": status,
            "time_s": time_s, "peak_rss_mib": 400.0 + repeat, "chamfer": chamfer,
            "normal_deg": 3.0 + repeat, "psnr": psnr, "jobs": jobs}


def _synthetic_rows():
    rows = []
    for sc, k in (("sphere_gold", 1.0), ("torus_ceramic", 0.8)):
        for r, t in enumerate((95.0, 90.0, 120.0)):
            rows.append(_row(sc, "preview", "preview", "", r, t * k, 0.0134 * k, 28.0 + r))
        for r, t in enumerate((300.0, 330.0, 310.0)):
            rows.append(_row(sc, "standard", "standard", "", r, t * k, 0.0079 * k, 30.5))
        rows.append(_row(sc, "iters 800", "standard", "shape.iters=800", 0, 170.0 * k,
                         0.0091 * k))
        rows.append(_row(sc, "rays | 2048", "standard", "shape.sampling.rays=2048", 0, 150.0,
                         0.0102, stage="both", psnr=29.0))
    rows.append(_row("sphere_gold", "broken", "standard", "shape.iters=5", 0, "", "",
                     status="failed: voxnero shape failed (exit 1)"))
    return rows


# ------------------------------------------------------------------------------ writers


def test_csv_and_markdown_hold_the_medians_presets_bold(tmp_path):
    rows = _synthetic_rows()
    T.write_csv(tmp_path / "tradeoff.csv", rows)
    back = T.read_csv(tmp_path / "tradeoff.csv")
    assert len(back) == len(rows)
    assert float(back[0]["time_s"]) == rows[0]["time_s"]  # floats survive exactly (repr)
    summ = T.summarise(back)
    md = T.render_markdown(summ)
    table = T.parse_markdown(md)
    # 2 scenes x 4 points; the failed run is not in the table
    assert len(table) == 8 and all(r["point"] != "broken" for r in table)
    with open(tmp_path / "tradeoff.csv", newline="") as fh:
        raw = [r for r in csv.DictReader(fh) if r["status"] == "ok"]
    fmt = {"time_s": 1, "peak_rss_mib": 0, "chamfer": 5, "normal_deg": 2, "psnr": 2}
    for t in table:
        mine = [r for r in raw if (r["scene"], r["stage"], r["preset"], r["overrides"])
                == (t["scene"], t["stage"], t["preset"], t["overrides"])]
        assert mine, t
        for m, nd in fmt.items():
            xs = [float(r[m]) for r in mine if r[m] != "nan"]
            if not xs:
                assert math.isnan(t[m])
                continue
            want = statistics.median(xs)  # independent median of the raw CSV strings
            assert t[m] == pytest.approx(round(want, nd), abs=0.51 * 10 ** -nd), (t, m)
    # the medians of 3 repeats: 95 (preview, gold), 310 (standard, gold)
    by = {(t["scene"], t["point"]): t for t in table}
    assert by["sphere_gold", "preview"]["time_s"] == 95.0
    assert by["sphere_gold", "standard"]["time_s"] == 310.0
    assert by["sphere_gold", "rays | 2048"]["psnr"] == 29.0
    lines = md.splitlines()
    assert any(ln.startswith("| **preview** | sphere_gold |") for ln in lines)
    assert any(ln.startswith("| **standard** | torus_ceramic |") for ln in lines)
    assert any(ln.startswith("| iters 800 | sphere_gold |") for ln in lines)
    assert not any("**iters 800**" in ln for ln in lines)
    assert "--jobs" not in md  # all runs alone


def test_markdown_notes_parallel_runs():
    rows = [_row("s", "preview", "preview", "", 0, 10.0, 0.01, jobs=2)]
    md = T.render_markdown(T.summarise(rows))
    assert "`--jobs 2`" in md


def _png_size(path: Path) -> tuple[int, int]:
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    assert data[12:16] == b"IHDR"
    return struct.unpack(">II", data[16:24])


def test_plot_is_a_png_of_the_requested_size(tmp_path):
    summ = T.summarise(_synthetic_rows())
    T.write_plot(summ, tmp_path / "a.png")
    assert _png_size(tmp_path / "a.png") == (1100, 450)
    T.write_plot(summ, tmp_path / "b.png", size=(6, 3), dpi=50)
    assert _png_size(tmp_path / "b.png") == (300, 150)
    from PIL import Image

    with Image.open(tmp_path / "a.png") as im:
        im.verify()
    # no stage-2 points: the second panel shows the normal error instead of an empty PSNR
    stage1 = T.summarise([_row("s", "preview", "preview", "", 0, 10.0, 0.01)])
    assert [m for m, _ in T.plot_panels(stage1)] == ["chamfer", "normal_deg"]
    assert [m for m, _ in T.plot_panels(summ)] == ["chamfer", "psnr"]
    T.write_plot(stage1, tmp_path / "c.png")
    assert _png_size(tmp_path / "c.png") == (1100, 450)


def test_a_point_run_on_many_scenes_is_named_once_per_panel():
    """A corpus sweep runs one point on every scene: its name labels one marker, not ten;
    presets keep their own bold names and a point without the panel's metric gets none."""
    summ = T.summarise(_synthetic_rows())
    named = T.labelled_points(summ, "chamfer")
    assert sorted(p for _, p in named) == ["iters 800", "rays | 2048"]
    assert ("sphere_gold", "iters 800") in named  # its first scene in the table
    # only the stage-2 point has a PSNR
    assert {p for _, p in T.labelled_points(summ, "psnr")} == {"rays | 2048"}


# ------------------------------------------------------------------------------ points


def test_points_parse_and_default_sweep_is_valid_config():
    from voxnero.config import resolve
    from voxnero.errors import ConfigError
    from voxnero.material.config import MaterialConfig
    from voxnero.shape.config import ShapeConfig

    p = T.parse_point("shape.grid.res=[32,64]")
    assert (p.preset, p.overrides) == ("standard", ("shape.grid.res=[32,64]",))
    q = T.parse_point("preview  shape.iters=5 material.iters=3")
    assert q.name == "preview shape.iters=5 material.iters=3" and q.stages() == {"shape",
                                                                                 "material"}
    assert q.for_stage("shape") == ["shape.iters=5"]
    with pytest.raises(ConfigError):
        T.parse_point("iters=5")  # no section: ambiguous
    with pytest.raises(ConfigError):
        T.parse_point("preview standard")

    pts = T.resolve_points(None)
    assert 8 <= len(pts) <= 12
    assert {"preview", "standard", "quality"} <= {p.name for p in pts if p.is_preset}
    knobs = [p for p in pts if not p.is_preset]
    # each knob varied alone, around one preset, and every override is a valid config key
    assert all(len(p.stages()) == 1 for p in knobs)
    for p in pts:
        resolve(ShapeConfig, "shape", p.preset, p.for_stage("shape"))
        resolve(MaterialConfig, "material", p.preset, p.for_stage("material"))
    shape_only = T.points_for_stage(pts, "shape")
    assert all(p.is_preset or p.stages() == {"shape"} for p in shape_only)
    assert len(T.points_for_stage(pts, "both")) == len(pts)
    assert {p.stages().pop() for p in knobs} == {"shape", "material"}


# ------------------------------------------------------------------------------ resume


def _fake_runner(calls, fail_on=None):
    def run(task):
        calls.append(task.key())
        if fail_on is not None and task.point.name == fail_on:
            raise KeyboardInterrupt  # the sweep is interrupted here
        r = _row(task.scene.name, task.point.name, task.point.preset,
                 " ".join(task.point.overrides), task.repeat, 10.0 + len(calls), 0.01)
        r["scene_path"] = str(task.scene)
        return r
    return run


def test_resume_skips_done_points(tmp_path):
    pts = [T.Point("preview", "preview"), T.Point("fast", "standard", ("shape.iters=5",)),
           T.Point("spp", "standard", ("material.render.spp_cos=1",))]
    tasks = T.plan([tmp_path / "sc"], pts, "shape", repeats=2)
    assert len(tasks) == 4  # the stage-2 knob is left out of a stage-1 sweep
    calls: list = []
    with pytest.raises(KeyboardInterrupt):
        T.sweep(tasks, tmp_path / "out", run=_fake_runner(calls, fail_on="fast"),
                log=lambda _: None)
    assert len(T.read_csv(tmp_path / "out" / "tradeoff.csv")) == 2  # preview x 2 kept
    calls2: list = []
    T.sweep(tasks, tmp_path / "out", run=_fake_runner(calls2), log=lambda _: None)
    assert calls2 == [t.key() for t in tasks[2:]]
    calls3: list = []
    rows = T.sweep(tasks, tmp_path / "out", run=_fake_runner(calls3), log=lambda _: None)
    assert calls3 == [] and len(rows) == 4
    # a failed row is retried and replaced, not duplicated
    rows[0]["status"] = "failed: x"
    T.write_csv(tmp_path / "out" / "tradeoff.csv", rows)
    calls4: list = []
    rows = T.sweep(tasks, tmp_path / "out", run=_fake_runner(calls4), log=lambda _: None)
    assert calls4 == [tasks[0].key()] and len(rows) == 4
    assert (tmp_path / "out" / "tradeoff.md").is_file()


def test_parallel_sweep_runs_each_task_once(tmp_path):
    pts = [T.Point(f"p{i}", "standard", (f"shape.iters={i + 1}",)) for i in range(5)]
    tasks = T.plan([tmp_path / "a", tmp_path / "b"], pts, "shape", repeats=1)
    calls: list = []
    rows = T.sweep(tasks, tmp_path / "out", jobs=2, run=_fake_runner(calls), log=lambda _: None)
    assert sorted(calls) == sorted(t.key() for t in tasks) and len(rows) == 10


# ------------------------------------------------------------------------------ check


def test_check_flags_25_percent_and_passes_15_percent():
    ref = {"time_s": 100.0, "chamfer": 0.0100, "psnr": 30.0, "normal_deg": 3.0}
    assert T.compare(ref, {**ref, "time_s": 115.0}, 0.2) == []
    assert T.compare(ref, {**ref, "time_s": 85.0, "chamfer": 0.0115}, 0.2) == []
    assert T.compare(ref, {**ref, "time_s": 125.0}, 0.2) == ["time_s"]
    assert T.compare(ref, {**ref, "time_s": 75.0}, 0.2) == ["time_s"]
    assert T.compare(ref, {**ref, "chamfer": 0.0125}, 0.2) == ["chamfer"]
    assert T.compare(ref, {**ref, "psnr": 22.5}, 0.2) == ["psnr"]
    assert T.compare(ref, {**ref, "normal_deg": 9.0}, 0.2) == []  # reported, not checked
    # no PSNR in the reference (stage 1): not checked; missing in the new run: fails
    assert T.compare({**ref, "psnr": float("nan")}, {**ref, "psnr": float("nan")}, 0.2) == []
    assert T.compare(ref, {**ref, "chamfer": float("nan")}, 0.2) == ["chamfer"]


@settings(max_examples=200, deadline=None)
@given(ratio=st.floats(0.3, 3.0), tol=st.floats(0.01, 0.5), ref=st.floats(1e-4, 1e4))
def test_check_is_a_relative_band(ratio, tol, ref):
    bad = T.compare({"time_s": ref}, {"time_s": ref * ratio}, tol, keys=("time_s",))
    if abs(ratio - 1) > tol * (1 + 1e-9) + 1e-9:
        assert bad == ["time_s"]
    elif abs(ratio - 1) < tol * (1 - 1e-9) - 1e-9:
        assert bad == []


def test_check_against_a_table(tmp_path):
    ref_rows = [_row("s", "preview", "preview", "", 0, 100.0, 0.010),
                _row("s", "fast", "standard", "shape.iters=5", 0, 50.0, 0.020)]
    md = T.render_markdown(T.summarise(ref_rows))
    (tmp_path / "README.md").write_text(f"# x\n\n{T.MARK_BEGIN}\n{md}{T.MARK_END}\n")
    ref = T.load_reference(tmp_path / "README.md")
    new = T.summarise([_row("s", "preview", "preview", "", 0, 115.0, 0.0088),
                       _row("s", "fast", "standard", "shape.iters=5", 0, 62.5, 0.020)])
    res = T.check(ref, new, 0.2)
    assert [c.ok for c in res] == [True, False] and res[1].failures == ["time_s"]
    text = T.render_check(res, 0.2)
    assert "1.25×" in text and "✘ time_s" in text
    # a point not re-run fails
    res = T.check(ref, new[:1], 0.2)
    assert res[1].failures == ["not re-run"]


# ------------------------------------------------------------------------------ README


def test_readme_replacement_keeps_the_rest_byte_identical(tmp_path):
    before = "# Title\r\n\r\nSome text — with ünïcode.\r\n\r\n"
    after = "\r\nMore text\r\n  trailing spaces   \r\n"
    readme = tmp_path / "README.md"
    readme.write_bytes((before + T.MARK_BEGIN + "\r\nold table\r\n" + T.MARK_END + after)
                       .encode())
    out = tmp_path / "docs" / "tradeoff"
    out.mkdir(parents=True)
    rows = [_row("s", "preview", "preview", "", 0, 100.0, 0.010)]
    md = T.render_markdown(T.summarise(rows))
    T.update_readme(readme, md, out / "tradeoff.png")
    raw = readme.read_bytes()
    pre = (before + T.MARK_BEGIN).encode()
    post = (T.MARK_END + after).encode()
    assert raw.startswith(pre) and raw.endswith(post)
    inner = raw[len(pre):-len(post)].decode()
    assert "old table" not in inner and "| **preview** | s |" in inner
    assert "![speed-accuracy trade](docs/tradeoff/tradeoff.png)" in inner
    assert "\n" not in inner.replace("\r\n", "")  # the file's CRLF kept
    once = raw
    T.update_readme(readme, md, out / "tradeoff.png")
    assert readme.read_bytes() == once  # idempotent


def test_readme_without_markers_is_refused(tmp_path):
    from voxnero.errors import ConfigError

    with pytest.raises(ConfigError):
        T.replace_between_markers("no markers here\n", "x")
    with pytest.raises(ConfigError):
        T.replace_between_markers(f"{T.MARK_END}\n{T.MARK_BEGIN}\n", "x")
    with pytest.raises(ConfigError):
        T.replace_between_markers(f"{T.MARK_BEGIN}{T.MARK_END}{T.MARK_BEGIN}{T.MARK_END}", "x")


# ------------------------------------------------------------------------------ children


def test_run_child_measures_wall_time_and_peak_rss(tmp_path):
    code = ("import time; b = bytearray(300 * 2**20); b[::4096] = b'x' * len(b[::4096]); "
            "time.sleep(0.3)")
    r = T.run_child([sys.executable, "-c", code], tmp_path / "big.log")
    small = T.run_child([sys.executable, "-c", "pass"], tmp_path / "small.log")
    assert r.rc == 0 and r.wall_s >= 0.3
    assert 300 <= r.peak_rss_mib < 300 + small.peak_rss_mib + 64
    assert small.peak_rss_mib < 100
    bad = T.run_child([sys.executable, "-c", "raise SystemExit(3)"], tmp_path / "bad.log")
    assert bad.rc == 3
    slow = T.run_child([sys.executable, "-c", "import time; time.sleep(30)"], tmp_path / "s.log",
                       timeout=0.5)
    assert slow.rc == 124 and slow.wall_s < 10


def _alive(pid: int) -> bool:
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except (OSError, IndexError):
        return False
    return state not in ("Z", "X")


@pytest.mark.skipif(not Path("/proc/self/stat").is_file(), reason="needs Linux /proc")
def test_kill_children_stops_the_command_too(tmp_path):
    pid_file = tmp_path / "pid"
    code = (f"import os, time; open({str(pid_file)!r}, 'w').write(str(os.getpid())); "
            "time.sleep(60)")
    res = {}
    th = threading.Thread(target=lambda: res.update(r=T.run_child([sys.executable, "-c", code],
                                                                  tmp_path / "k.log")))
    th.start()
    t0 = time.time()
    while not (pid_file.is_file() and pid_file.read_text()) and time.time() - t0 < 20:
        time.sleep(0.05)
    pid = int(pid_file.read_text())
    assert _alive(pid)
    T.kill_children()
    th.join(20)
    assert not th.is_alive() and res["r"].rc != 0 and res["r"].wall_s < 30
    t0 = time.time()
    while _alive(pid) and time.time() - t0 < 5:
        time.sleep(0.05)
    assert not _alive(pid)  # the command itself, not only the launcher


# ------------------------------------------------------------------------------ end to end


@pytest.fixture(scope="module")
def tiny_scene(tmp_path_factory):
    out = tmp_path_factory.mktemp("tradeoff") / "sphere"
    subprocess.run([sys.executable, "-m", "voxnero", "synth", "sphere", "--preset", "tiny",
                    "--out", str(out)], check=True, capture_output=True, cwd=REPO)
    return out


def test_end_to_end_tiny_scene(tiny_scene, tmp_path, capsys):
    out = tmp_path / "sweep"
    rc = T.main(["--scenes", str(tiny_scene), "--out", str(out), "--points", TINY])
    assert rc == 0
    rows = T.read_csv(out / "tradeoff.csv")
    assert len(rows) == 1 and rows[0]["status"] == "ok"
    r = rows[0]
    assert math.isfinite(float(r["chamfer"])) and 0 < float(r["chamfer"]) < 1
    assert math.isfinite(float(r["normal_deg"]))
    # wall time of the command covers the trainer's own clock, and both are positive
    assert float(r["time_s"]) >= float(r["shape_train_s"]) > 0
    assert 50 < float(r["peak_rss_mib"]) < 8000
    assert r["psnr"] == "nan"  # stage 1 only
    assert (out / "tradeoff.md").read_text().count("| " + TINY + " |") == 1
    assert _png_size(out / "tradeoff.png") == (1100, 450)
    capsys.readouterr()
    # resumed: nothing re-run; --check on its own table passes without running anything
    assert T.main(["--scenes", str(tiny_scene), "--out", str(out), "--points", TINY]) == 0
    assert "0 to do" in capsys.readouterr().out
    assert T.main(["--check", str(out / "tradeoff.md"), "--scenes", str(tiny_scene), "--out",
                   str(out)]) == 0
    # the new run 25 % off a reference Chamfer fails the check, 15 % off passes
    ref, cd = tmp_path / "ref.csv", float(r["chamfer"])
    for dev, want in ((1.25, 1), (1.15, 0)):
        rows[0]["chamfer"] = cd / dev
        T.write_csv(ref, rows)
        assert T.main(["--check", str(ref), "--out", str(out)]) == want
