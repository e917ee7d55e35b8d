#!/usr/bin/env python
"""Measure the speed-accuracy trade of VoxNeRO's presets and knobs.

Each *point* is a preset plus optional ``key=value`` overrides (full keys: ``shape.*`` for stage
1, ``material.*`` for stage 2). For every scene and point the training command runs as its own
subprocess with one torch thread, then ``voxnero eval`` scores it:

- ``--stage shape``: ``voxnero shape SCENE --no-eval`` (timed), ``voxnero eval RUN``;
- ``--stage material``: the point's stage-1 run (made once per scene and stage-1 config, not
  timed), ``voxnero material RUN material.eval_views=0`` (timed), ``voxnero eval MATERIAL_DIR``;
- ``--stage both``: both training commands timed (the stage-1 run of equal stage-1 configs is
  shared between points and its time counted in each).

Recorded per run: wall time of the training command(s) (what the user waits for; the commands'
own in-training evaluations are switched off, ``voxnero eval`` is not counted), the trainers' own
clocks, peak RSS of the child (``os.wait4``), Chamfer, normal error and (stage 2) novel-view
PSNR. Written into ``--out``: ``tradeoff.csv`` (every run), ``tradeoff.md`` (median per point,
presets in bold) and ``tradeoff.png`` (time vs Chamfer and time vs PSNR). A run whose row is
already in the CSV is skipped, so an interrupted sweep continues where it stopped.

Examples::

    python tools/tradeoff.py --scenes /work/shared/data/sphere_gold \\
        /work/shared/data/torus_ceramic --out docs/tradeoff --jobs 2
    python tools/tradeoff.py --scenes S --out /tmp/t --points preview "standard shape.iters=800" \\
        shape.grid.res=[32,64]
    python tools/tradeoff.py --out docs/tradeoff --readme README.md     # tables from the CSV only
    python tools/tradeoff.py --check README.md --scenes S1 S2 --out /tmp/check --tolerance 0.2

``--points`` items: a preset name, a YAML spec file (``points: [{name, preset, overrides}]``,
see ``tools/tradeoff_configs/default.yaml``, the default), a single ``key=value`` (the ``--base``
preset with that override) or one quoted item ``"PRESET key=value key=value"``.
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import json
import math
import os
import re
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ThreadPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
DEFAULT_SPEC = REPO / "tools" / "tradeoff_configs" / "default.yaml"
STAGES = ("shape", "material", "both")
MARK_BEGIN = "<!-- tradeoff:begin -->"
MARK_END = "<!-- tradeoff:end -->"

FIELDS = ["scene", "scene_path", "point", "preset", "overrides", "stage", "repeat", "status",
          "time_s", "shape_s", "material_s", "shape_train_s", "material_train_s",
          "peak_rss_mib", "chamfer", "normal_deg", "psnr", "jobs", "load1", "started", "host"]
"""Columns of ``tradeoff.csv``: one row per (scene, point, stage, repeat). ``time_s`` is the
wall time (s) of the timed training command(s); ``shape_s`` / ``material_s`` the wall time of each
(``shape_s`` is also filled, untimed, for ``--stage material``); ``*_train_s`` the trainers' own
clocks; ``peak_rss_mib`` the largest peak RSS of the timed children (MiB); ``chamfer`` the NeRO
Chamfer distance (input frame); ``normal_deg`` the mean normal error (degrees); ``psnr`` the
novel-view PSNR (dB, stage 2 only); ``jobs`` how many runs shared the machine; ``load1`` the
1-minute load average when the run started."""

METRICS = ("time_s", "peak_rss_mib", "chamfer", "normal_deg", "psnr")
CHECKED = ("time_s", "chamfer", "psnr")
"""Quantities ``--check`` compares (relative tolerance); the others are reported only."""


# ---------------------------------------------------------------------------------------------
# points


@dataclass(frozen=True)
class Point:
    """One configuration of the sweep: a preset plus ``key=value`` overrides (full keys)."""

    name: str
    preset: str
    overrides: tuple[str, ...] = ()

    @property
    def is_preset(self) -> bool:
        """Whether the point is a preset as shipped (no overrides)."""
        return not self.overrides

    @property
    def config(self) -> str:
        """``"PRESET key=value ..."``: the point as one ``--points`` item."""
        return " ".join((self.preset, *self.overrides))

    def stages(self) -> set[str]:
        """Sections its overrides address (``{"shape"}``, ``{"material"}``, both or none)."""
        return {o.split("=", 1)[0].split(".", 1)[0] for o in self.overrides}

    def for_stage(self, stage: str) -> list[str]:
        """The overrides of one section (``"shape"`` or ``"material"``)."""
        return [o for o in self.overrides if o.split(".", 1)[0] == stage]


def _check_override(item: str, where: str) -> str:
    from voxnero.errors import ConfigError

    key = item.split("=", 1)[0]
    if "=" not in item or key.split(".", 1)[0] not in ("shape", "material") or "." not in key:
        raise ConfigError(f"{where}: override {item!r} needs a full key under shape. or material.",
                          fix="write e.g. shape.iters=800 or material.render.spp_cos=2")
    return item.strip()


def parse_point(item: str, base: str = "standard") -> Point:
    """One ``--points`` item: ``PRESET``, ``key=value`` or ``"PRESET key=value ..."``.

    A bare override (no preset word) applies to ``base``. The name is the item as written
    (normalised spacing), so equal items are the same point.
    """
    from voxnero.errors import ConfigError

    words = item.split()
    presets = [w for w in words if "=" not in w]
    if len(presets) > 1:
        raise ConfigError(f"--points item {item!r} names more than one preset {presets}",
                          fix="quote one point per item: \"standard shape.iters=800\"")
    ov = tuple(_check_override(w, "--points") for w in words if "=" in w)
    preset = presets[0] if presets else base
    return Point(" ".join(words), preset, ov)


def load_spec(path: str | Path) -> list[Point]:
    """Points of a YAML sweep spec: ``points: [{name, preset, overrides: [k=v, ...]}]``."""
    import yaml

    from voxnero.errors import ConfigError

    path = Path(path)
    try:
        doc = yaml.safe_load(path.read_text()) or {}
    except (OSError, yaml.YAMLError) as e:
        raise ConfigError(f"cannot read the sweep spec: {e}", path=path) from None
    items = doc.get("points") if isinstance(doc, dict) else None
    if not isinstance(items, list) or not items:
        raise ConfigError("a sweep spec needs a non-empty list 'points'", path=path,
                          fix="points: [{name: fast, preset: standard, "
                              "overrides: [shape.iters=800]}]")
    out = []
    for i, it in enumerate(items):
        if not isinstance(it, dict) or "preset" not in it or set(it) - {"name", "preset",
                                                                          "overrides"}:
            raise ConfigError(f"points[{i}] must be a mapping with preset (and optional name, "
                              f"overrides), got {it!r}", path=path)
        ov = tuple(_check_override(str(o), f"{path} points[{i}]") for o in it.get("overrides")
                   or [])
        name = str(it.get("name") or " ".join((it["preset"], *ov)))
        out.append(Point(name, str(it["preset"]), ov))
    return out


def resolve_points(items: Sequence[str] | None, base: str = "standard") -> list[Point]:
    """``--points`` items (presets, ``key=value``, quoted points, YAML specs) to points.

    Raises:
        ConfigError: two different points share a name.
    """
    from voxnero.errors import ConfigError

    points: list[Point] = []
    for item in items or [str(DEFAULT_SPEC)]:
        if item.endswith((".yaml", ".yml")) and "=" not in item:
            points += load_spec(item)
        else:
            points.append(parse_point(item, base))
    seen: dict[str, Point] = {}
    uniq = []
    for p in points:
        if p.name in seen:
            if seen[p.name] != p:
                raise ConfigError(f"two points are named {p.name!r}", fix="rename one of them")
            continue
        seen[p.name] = p
        uniq.append(p)
    return uniq


def points_for_stage(points: Iterable[Point], stage: str) -> list[Point]:
    """Points meaningful for ``stage``: presets, and points with overrides of a timed stage.

    A stage-2-only knob is dropped from a stage-1 sweep (it would repeat its preset), and a
    stage-1-only knob from a stage-2 sweep (stage 1 is not timed there).
    """
    timed = {"shape": {"shape"}, "material": {"material"}, "both": {"shape", "material"}}[stage]
    return [p for p in points if p.is_preset or p.stages() & timed]


# ---------------------------------------------------------------------------------------------
# child processes


@dataclass
class ChildResult:
    """What one subprocess cost: exit code, wall time (s), peak RSS (MiB)."""

    rc: int
    wall_s: float
    peak_rss_mib: float


def child_env() -> dict[str, str]:
    """Environment of the children: one OpenMP / MKL thread, unbuffered output."""
    env = dict(os.environ)
    env.update(OMP_NUM_THREADS="1", MKL_NUM_THREADS="1", OPENBLAS_NUM_THREADS="1",
               PYTHONUNBUFFERED="1")
    return env


_LAUNCHER = """
import json, os, subprocess, sys, time
t0 = time.perf_counter()
p = subprocess.Popen(sys.argv[2:])
_, status, usage = os.wait4(p.pid, 0)
wall = time.perf_counter() - t0
p.returncode = os.waitstatus_to_exitcode(status)
kib = usage.ru_maxrss / (1024.0 if sys.platform == "darwin" else 1.0)
with open(sys.argv[1], "w") as fh:
    json.dump({"rc": p.returncode, "wall_s": wall, "peak_rss_mib": kib / 1024.0}, fh)
"""
"""A small Python that runs the command and reports its exit code, wall time and peak RSS.

Why not ``os.wait4`` on the command directly: Python starts children with ``vfork`` (or
``fork``), and Linux carries the parent's resident-set high-water mark over into the child's
``ru_maxrss`` across the ``exec``; a sweep started from a process holding torch (a test, a
notebook) would report that process's RSS for every small child. Started from this launcher,
the floor is the launcher's own ~10 MiB."""


_LIVE: set[int] = set()
"""Process groups of the children running now (killed if the sweep is interrupted)."""
_LIVE_LOCK = threading.Lock()


def kill_children() -> None:
    """SIGKILL every running child's process group (they run in their own sessions, so a
    Ctrl-C at the terminal does not reach them)."""
    with _LIVE_LOCK:
        for pgid in list(_LIVE):
            try:
                os.killpg(pgid, signal.SIGKILL)
            except ProcessLookupError:
                pass


def run_child(cmd: Sequence[str], log: Path, timeout: float | None = None) -> ChildResult:
    """Run ``cmd``, stdout + stderr into ``log``; time it and read its peak RSS.

    The command runs under :data:`_LAUNCHER` in its own session: peak RSS is ``ru_maxrss`` of
    ``os.wait4`` on the command (the largest resident set of it or of a descendant it waited
    for), wall time is measured around it.

    Returns:
        exit code (``-signal`` if killed; 124 after ``timeout`` seconds), wall seconds, MiB.
    """
    log.parent.mkdir(parents=True, exist_ok=True)
    res = log.with_name(log.name + ".result.json")
    res.unlink(missing_ok=True)
    with open(log, "wb") as fh:
        fh.write(("$ " + " ".join(cmd) + "\n").encode())
        fh.flush()
        t0 = time.perf_counter()
        proc = subprocess.Popen([sys.executable, "-c", _LAUNCHER, str(res), *cmd], stdout=fh,
                                stderr=subprocess.STDOUT, env=child_env(), cwd=REPO,
                                start_new_session=True)
        with _LIVE_LOCK:
            _LIVE.add(proc.pid)
        try:
            proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            os.killpg(proc.pid, signal.SIGKILL)  # the launcher and the command
            proc.wait()
            return ChildResult(124, time.perf_counter() - t0, float("nan"))
        except BaseException:  # Ctrl-C: do not leave the training running on its own
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()
            raise
        finally:
            with _LIVE_LOCK:
                _LIVE.discard(proc.pid)
    info = _json(res)
    if not info:
        return ChildResult(proc.returncode or 1, time.perf_counter() - t0, float("nan"))
    return ChildResult(int(info["rc"]), float(info["wall_s"]), float(info["peak_rss_mib"]))


def _voxnero(*args: str) -> list[str]:
    return [sys.executable, "-m", "voxnero", *args]


def _slug(text: str) -> str:
    h = hashlib.sha1(text.encode()).hexdigest()[:8]
    s = re.sub(r"[^A-Za-z0-9]+", "_", text).strip("_")[:40]
    return f"{s}-{h}"


def _json(path: Path) -> dict:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return {}


def _eval_metrics(metrics: dict) -> dict[str, float]:
    """Chamfer, mean normal error and novel-view PSNR from ``voxnero eval``'s metrics.json."""
    nan = float("nan")
    ch = metrics.get("chamfer")
    ne = metrics.get("normals")
    nv = metrics.get("novel_view")
    return {"chamfer": float(ch["cd"]) if isinstance(ch, dict) else nan,
            "normal_deg": float(ne["mean_deg"]) if isinstance(ne, dict) else nan,
            "psnr": float(nv["psnr"]) if isinstance(nv, dict) else nan}


@dataclass
class Task:
    """One run of the sweep: a point on a scene in a stage, the ``repeat``-th time."""

    scene: Path
    point: Point
    stage: str
    repeat: int = 0

    def key(self) -> tuple[str, str, str, str, int]:
        """Identity of the run in the CSV (scene name, stage, preset, overrides, repeat)."""
        return (self.scene.name, self.stage, self.point.preset, " ".join(self.point.overrides),
                self.repeat)


def row_key(row: dict) -> tuple[str, str, str, str, int]:
    """:meth:`Task.key` of a CSV row."""
    return (row["scene"], row["stage"], row["preset"], row["overrides"], int(row["repeat"]))


class Runner:
    """Runs tasks: training command(s) then ``voxnero eval``; shares equal stage-1 runs."""

    def __init__(self, out: Path, jobs: int = 1, timeout: float | None = None,
                 log: Callable[[str], None] = print):
        self.out, self.jobs, self.timeout, self.log = out, jobs, timeout, log
        self._locks: dict[str, threading.Lock] = {}
        self._guard = threading.Lock()

    def _lock(self, key: str) -> threading.Lock:
        with self._guard:
            return self._locks.setdefault(key, threading.Lock())

    def shape_run(self, scene: Path, point: Point, repeat: int) -> tuple[Path, dict]:
        """The stage-1 run of (scene, preset, shape overrides, repeat): made once, then reused.

        Returns:
            run folder, ``{"rc", "wall_s", "peak_rss_mib", "train_s"}`` of its (first) making.
        """
        cfg = " ".join((point.preset, *point.for_stage("shape")))
        d = self.out / "runs" / scene.name / f"shape-{_slug(cfg)}" / f"r{repeat}"
        with self._lock(str(d)):
            done = _json(d / "tradeoff_child.json")
            if done.get("rc") == 0 and (d / "mesh.ply").is_file():
                return d, done
            shutil.rmtree(d, ignore_errors=True)  # never resume half a run: it would skew time
            cmd = _voxnero("shape", str(scene), "--preset", point.preset, "--out", str(d),
                           "--no-eval", "--no-progress", "shape.threads=1",
                           *point.for_stage("shape"))
            res = run_child(cmd, d.parent / f"r{repeat}.shape.log", self.timeout)
            info = {"rc": res.rc, "wall_s": res.wall_s, "peak_rss_mib": res.peak_rss_mib,
                    "train_s": _json(d / "shape.json").get("train_time_s", float("nan"))}
            if d.is_dir():
                (d / "tradeoff_child.json").write_text(json.dumps(info))
            return d, info

    def evaluate(self, target: Path, scene: Path) -> dict[str, float]:
        """``voxnero eval TARGET --scene SCENE --out TARGET/eval`` (reused if already there)."""
        metrics = target / "eval" / "metrics.json"
        if not metrics.is_file():
            res = run_child(_voxnero("eval", str(target), "--scene", str(scene), "--out",
                                     str(target / "eval")), target / "eval.log", self.timeout)
            if res.rc != 0:
                raise RuntimeError(f"voxnero eval failed (exit {res.rc}); see {target}/eval.log")
        return _eval_metrics(_json(metrics))

    def run(self, task: Task) -> dict:
        """Run one task; returns its CSV row (``status`` "ok" or "failed: ...")."""
        p, scene = task.point, task.scene
        row = {k: "" for k in FIELDS}
        row.update(scene=scene.name, scene_path=str(scene), point=p.name, preset=p.preset,
                   overrides=" ".join(p.overrides), stage=task.stage, repeat=task.repeat,
                   jobs=self.jobs, load1=round(os.getloadavg()[0], 2),
                   started=time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                   host=socket.gethostname())
        try:
            shape_repeat = 0 if task.stage == "material" else task.repeat
            sdir, s = self.shape_run(scene, p, shape_repeat)
            if s["rc"] != 0:
                raise RuntimeError(f"voxnero shape failed (exit {s['rc']}); see {sdir}.shape.log")
            row.update(shape_s=s["wall_s"], shape_train_s=s["train_s"])
            timed_rss = [s["peak_rss_mib"]] if task.stage != "material" else []
            target = sdir
            if task.stage in ("material", "both"):
                mdir = (self.out / "runs" / scene.name / f"material-{_slug(p.config)}"
                        / f"r{task.repeat}")
                shutil.rmtree(mdir, ignore_errors=True)
                cmd = _voxnero("material", str(sdir), "--scene", str(scene), "--preset",
                               p.preset, "--out", str(mdir), "--no-progress",
                               "material.threads=1", "material.eval_views=0",
                               *p.for_stage("material"))
                m = run_child(cmd, mdir.parent / f"r{task.repeat}.material.log", self.timeout)
                if m.rc != 0:
                    raise RuntimeError(f"voxnero material failed (exit {m.rc}); see "
                                       f"{mdir}.material.log")
                mj = _json(mdir / "materials.json")
                row.update(material_s=m.wall_s,
                           material_train_s=(mj.get("times") or {}).get("train_s", ""))
                timed_rss.append(m.peak_rss_mib)
                target = mdir
            row["time_s"] = {"shape": row["shape_s"], "material": row["material_s"],
                             "both": (row["shape_s"] or 0) + (row["material_s"] or 0)
                             }[task.stage]
            row["peak_rss_mib"] = max(timed_rss)
            row.update(self.evaluate(target, scene))
            row["status"] = "ok"
        except RuntimeError as e:
            row["status"] = f"failed: {e}"
        return row


# ---------------------------------------------------------------------------------------------
# CSV, summary, Markdown, plot


def read_csv(path: Path) -> list[dict]:
    """Rows of a ``tradeoff.csv`` (values as strings; missing file: no rows)."""
    if not path.is_file():
        return []
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def write_csv(path: Path, rows: Iterable[dict]) -> None:
    """Write rows (atomically: a temp file renamed over ``path``)."""
    tmp = path.with_suffix(".csv.tmp")
    with open(tmp, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=FIELDS, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: _fmt_csv(r.get(k, "")) for k in FIELDS})
    os.replace(tmp, path)


def _fmt_csv(v: object) -> str:
    if isinstance(v, float):
        return "nan" if math.isnan(v) else repr(v)
    return str(v)


def _num(v: object) -> float:
    try:
        return float(v)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return float("nan")


def merge_rows(old: list[dict], new: Iterable[dict]) -> list[dict]:
    """``old`` with each new row replacing an earlier row of the same key (kept in order)."""
    out = {row_key(r): r for r in old}
    for r in new:
        out[row_key(r)] = r
    return list(out.values())


def is_done(row: dict) -> bool:
    """Whether a CSV row is a finished, successful run (the resume test)."""
    return row.get("status") == "ok"


@dataclass
class Summary:
    """Median over the successful repeats of one (scene, stage, point)."""

    scene: str
    stage: str
    point: str
    preset: str
    overrides: str
    runs: int
    values: dict[str, float] = field(default_factory=dict)
    jobs: int = 1

    @property
    def is_preset(self) -> bool:
        """A preset as shipped (drawn in bold / highlighted)."""
        return not self.overrides


def summarise(rows: Iterable[dict]) -> list[Summary]:
    """Median per (scene, stage, preset, overrides) of the ``status == ok`` rows, in CSV order."""
    groups: dict[tuple, list[dict]] = {}
    for r in rows:
        if is_done(r):
            groups.setdefault(row_key(r)[:4], []).append(r)
    out = []
    for (scene, stage, preset, ov), rs in groups.items():
        vals = {}
        for m in METRICS:
            xs = [x for x in (_num(r.get(m)) for r in rs) if not math.isnan(x)]
            vals[m] = statistics.median(xs) if xs else float("nan")
        jobs = max(int(j) if not math.isnan(j := _num(r.get("jobs"))) else 1 for r in rs)
        out.append(Summary(scene, stage, rs[0]["point"], preset, ov, len(rs), vals, jobs))
    return out


_FMT = {"time_s": "{:.1f}", "peak_rss_mib": "{:.0f}", "chamfer": "{:.5f}", "normal_deg": "{:.2f}",
        "psnr": "{:.2f}"}
_HEAD = ["point", "scene", "stage", "config", "time s", "peak RSS MiB", "Chamfer",
         "normal err °", "PSNR dB", "runs"]


def _cell(metric: str, v: float) -> str:
    return "—" if math.isnan(v) else _FMT[metric].format(v)


def render_markdown(summaries: Sequence[Summary], note: str = "") -> str:
    """The Markdown table (one row per scene, stage and point; presets in bold) and notes.

    Times are medians over ``runs`` of the wall time of the training command(s); every value is
    the CSV's median rounded as in :data:`_FMT`.
    """
    lines = ["| " + " | ".join(_HEAD) + " |", "|" + "---|" * len(_HEAD)]
    for s in summaries:
        name = f"**{s.point}**" if s.is_preset else s.point.replace("|", "\\|")
        cfg = " ".join(x for x in (s.preset, s.overrides) if x).replace("|", "\\|")
        cells = [name, s.scene, s.stage, f"`{cfg}`"] + [_cell(m, s.values[m]) for m in METRICS]
        lines.append("| " + " | ".join(cells + [str(s.runs)]) + " |")
    notes = ["Time: wall-clock seconds of the training command(s) the user waits for "
             "(`voxnero shape --no-eval`; stage 2 `voxnero material material.eval_views=0`; "
             "both: their sum), median over the runs, one torch thread per run; `voxnero eval` "
             "is not counted. Chamfer: NeRO protocol (`voxnero eval`, input frame); normal "
             "error: mean, degrees, test views; PSNR: novel views of the exported asset "
             "(stage 2). **Bold**: presets as shipped."]
    if any(s.jobs > 1 for s in summaries):
        j = max(s.jobs for s in summaries)
        notes.append(f"Times were taken with `--jobs {j}`: {j} runs at once on the machine.")
    if note:
        notes.append(note)
    return "\n".join(lines) + "\n\n" + "\n\n".join(notes) + "\n"


def parse_markdown(text: str) -> list[dict]:
    """Rows of a table written by :func:`render_markdown` (e.g. inside a README).

    Returns:
        dicts with scene, stage, point, preset, overrides and the metric values (float, NaN for
        "—"), the keys of :data:`METRICS`.
    """
    rows = []
    header = None
    for line in text.splitlines():
        line = line.strip()
        if not line.startswith("|"):
            header = None if not line else header
            continue
        cells = [c.strip() for c in re.split(r"(?<!\\)\|", line)[1:-1]]
        if cells[:3] == _HEAD[:3]:
            header = cells
            continue
        if header is None or set("".join(cells)) <= set("-: "):
            continue
        d = dict(zip(header, cells, strict=False))
        cfg = d["config"].strip("`").replace("\\|", "|").split()
        point = d["point"].replace("\\|", "|")
        point = point[2:-2] if point.startswith("**") and point.endswith("**") else point
        r = {"scene": d["scene"], "stage": d["stage"], "point": point, "preset": cfg[0],
             "overrides": " ".join(cfg[1:])}
        for m, h in zip(METRICS, _HEAD[4:9], strict=True):
            r[m] = _num(d.get(h, "").replace("—", "nan"))
        rows.append(r)
    return rows


def _short(name: str, n: int = 28) -> str:
    return name if len(name) <= n else name[:n - 1] + "…"


def write_plot(summaries: Sequence[Summary], path: Path, size: tuple[float, float] = (11, 4.5),
               dpi: int = 100) -> None:
    """``tradeoff.png``: time vs Chamfer and time vs PSNR, log time, one marker per scene.

    Presets are large filled markers with their name in bold beside them; other points small,
    hollow, with their name in small grey type. The image is ``size × dpi`` pixels exactly
    (1100 × 450 by default).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    markers = ["o", "s", "^", "D", "v", "P", "X", "*"]
    scenes = list(dict.fromkeys(s.scene for s in summaries))
    fig, axes = plt.subplots(1, 2, figsize=size, dpi=dpi)
    for ax, metric, label in ((axes[0], "chamfer", "Chamfer (lower is better)"),
                              (axes[1], "psnr", "novel-view PSNR dB (higher is better)")):
        any_pt = False
        for i, sc in enumerate(scenes):
            mk = markers[i % len(markers)]
            pts = [s for s in summaries if s.scene == sc and not math.isnan(s.values[metric])
                   and not math.isnan(s.values["time_s"]) and s.values["time_s"] > 0]
            if not pts:
                continue
            any_pt = True
            col = f"C{i % 10}"
            others = [s for s in pts if not s.is_preset]
            pres = [s for s in pts if s.is_preset]
            leg = sc
            if others:
                ax.scatter([s.values["time_s"] for s in others],
                           [s.values[metric] for s in others], marker=mk, facecolors="none",
                           edgecolors=col, s=36, label=leg)
                leg = None
                for s in others:
                    ax.annotate(_short(s.point), (s.values["time_s"], s.values[metric]),
                                xytext=(4, -9),
                                textcoords="offset points", fontsize=6, color="0.35"
                                ).set_in_layout(False)
            if pres:
                ax.scatter([s.values["time_s"] for s in pres], [s.values[metric] for s in pres],
                           marker=mk, color=col, edgecolors="black", s=110, zorder=3,
                           label=leg)
                for s in pres:
                    ax.annotate(s.point, (s.values["time_s"], s.values[metric]), xytext=(6, 6),
                                textcoords="offset points", fontsize=9, fontweight="bold"
                                ).set_in_layout(False)
        ax.set_xscale("log")
        ax.margins(x=0.12, y=0.1)
        ax.xaxis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
        ax.xaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_xlabel("training wall time (s, log)")
        ax.set_ylabel(label)
        ax.grid(True, which="both", alpha=0.3)
        if any_pt:
            ax.legend(fontsize=8, loc="best")
        else:
            ax.text(0.5, 0.5, "no points with this metric\n(PSNR needs --stage material/both)",
                    ha="center", va="center", transform=ax.transAxes)
    fig.suptitle("VoxNeRO speed-accuracy trade (medians; bold markers: presets)")
    fig.subplots_adjust(left=0.07, right=0.98, bottom=0.12, top=0.88, wspace=0.3)
    fig.savefig(path, dpi=dpi)
    plt.close(fig)


def write_outputs(out: Path, rows: list[dict], note: str = "") -> str:
    """``tradeoff.md`` and ``tradeoff.png`` from the CSV rows; returns the Markdown."""
    summ = summarise(rows)
    md = render_markdown(summ, note)
    (out / "tradeoff.md").write_text(md)
    write_plot(summ, out / "tradeoff.png")
    return md


def replace_between_markers(text: str, block: str, begin: str = MARK_BEGIN,
                            end: str = MARK_END) -> str:
    """Replace what lies between the two markers with ``block`` (markers kept, rest untouched).

    Raises:
        ConfigError: a marker is missing, repeated or out of order.
    """
    from voxnero.errors import ConfigError

    if text.count(begin) != 1 or text.count(end) != 1 or text.index(begin) > text.index(end):
        raise ConfigError(f"the file needs exactly one {begin} followed by one {end}",
                          fix="put both markers on their own lines where the table goes")
    i = text.index(begin) + len(begin)
    j = text.index(end)
    nl = "\r\n" if "\r\n" in text else "\n"
    body = block.replace("\r\n", "\n").strip("\n").replace("\n", nl)
    return text[:i] + nl + body + nl + text[j:]


def update_readme(readme: Path, md: str, png: Path) -> None:
    """Put the table and the image link between the tradeoff markers of ``readme``."""
    rel = os.path.relpath(png.resolve(), readme.resolve().parent)
    block = md.rstrip("\n") + f"\n\n![speed-accuracy trade]({Path(rel).as_posix()})\n"
    raw = readme.read_bytes().decode("utf-8")
    readme.write_bytes(replace_between_markers(raw, block).encode("utf-8"))


# ---------------------------------------------------------------------------------------------
# check


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
                        fix="pass a file holding a table written by tools/tradeoff.py")
    return rows


# ---------------------------------------------------------------------------------------------
# sweep


def plan(scenes: Sequence[Path], points: Sequence[Point], stage: str, repeats: int) -> list[Task]:
    """Every (scene, point, repeat) of a sweep, points in order, repeats innermost."""
    return [Task(sc, p, stage, k) for p in points_for_stage(points, stage) for sc in scenes
            for k in range(repeats)]


def sweep(tasks: Sequence[Task], out: Path, jobs: int = 1, timeout: float | None = None,
          run: Callable[[Task], dict] | None = None, log: Callable[[str], None] = print,
          note: str = "") -> list[dict]:
    """Run the tasks not yet in ``out/tradeoff.csv`` and rewrite the outputs after each.

    Args:
        tasks: runs to make; those whose key has an ``ok`` row in the CSV are skipped.
        out: output folder.
        jobs: runs at once.
        run: the function making one run (default :meth:`Runner.run`; tests pass a fake).

    Returns:
        all CSV rows afterwards.
    """
    out.mkdir(parents=True, exist_ok=True)
    csv_path = out / "tradeoff.csv"
    rows = read_csv(csv_path)
    done = {row_key(r) for r in rows if is_done(r)}
    todo = [t for t in tasks if t.key() not in done]
    log(f"[tradeoff] {len(tasks)} runs, {len(tasks) - len(todo)} already in {csv_path}, "
        f"{len(todo)} to do ({jobs} at a time)")
    runner = run or Runner(out, min(jobs, max(1, len(todo))), timeout, log).run
    lock = threading.Lock()

    def _record(row: dict) -> None:
        nonlocal rows
        with lock:
            rows = merge_rows(rows, [row])
            write_csv(csv_path, rows)
        log(f"[tradeoff] {row['scene']} / {row['point']} / {row['stage']} #{row['repeat']}: "
            f"{row['status']}, time {_cell('time_s', _num(row['time_s']))} s, Chamfer "
            f"{_cell('chamfer', _num(row['chamfer']))}, PSNR {_cell('psnr', _num(row['psnr']))}")

    if jobs <= 1:
        for t in todo:
            _record(runner(t))
    else:
        pool = ThreadPoolExecutor(max_workers=jobs)
        try:
            for f in as_completed([pool.submit(runner, t) for t in todo]):
                _record(f.result())
        except BaseException:
            pool.shutdown(wait=False, cancel_futures=True)
            kill_children()  # the workers' children would otherwise run on unobserved
            raise
        pool.shutdown()
    if rows:
        write_outputs(out, rows, note)
    return rows


def _machine_note() -> str:
    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO, text=True,
                                capture_output=True, check=False).stdout.strip()
    except OSError:
        commit = ""
    return (f"Machine: {socket.gethostname()}, {os.cpu_count()} CPUs; written "
            f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}"
            + (f" at commit {commit}" if commit else "") + " by `tools/tradeoff.py`.")


def _scene_map(scenes: Sequence[str]) -> dict[str, Path]:
    return {Path(s).resolve().name: Path(s).resolve() for s in scenes}


def main(argv: list[str] | None = None) -> int:
    """Command line; returns the exit code (1: ``--check`` out of tolerance or a run failed)."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 epilog=__doc__.split("\n\n", 1)[1],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", nargs="+", default=[], help="scene folders")
    ap.add_argument("--out", required=True, help="output folder (tradeoff.csv/.md/.png, runs/)")
    ap.add_argument("--points", nargs="+", default=None,
                    help="presets, key=value (on --base), \"PRESET k=v ...\" or YAML specs "
                         f"(default: {DEFAULT_SPEC.relative_to(REPO)})")
    ap.add_argument("--base", default="standard", help="preset of bare key=value points")
    ap.add_argument("--stage", choices=STAGES, default="shape", help="what is timed")
    ap.add_argument("--repeats", type=int, default=1, help="runs per point (median reported)")
    ap.add_argument("--jobs", type=int, default=1, help="points run at once")
    ap.add_argument("--timeout", type=float, default=None, help="seconds per child command")
    ap.add_argument("--check", default=None, metavar="TABLE",
                    help="re-run the points of a previous table (.md, README or .csv) into "
                         "--out (runs already there are reused: use a fresh folder) and "
                         "compare time and accuracy")
    ap.add_argument("--tolerance", type=float, default=0.2, help="relative, for --check")
    ap.add_argument("--readme", default=None,
                    help="put the table + image link between the tradeoff markers of this file")
    ap.add_argument("--list", action="store_true", help="print the runs and exit")
    args = ap.parse_args(argv)

    from voxnero.errors import VoxneroError

    try:
        return _main(args)
    except VoxneroError as e:
        print(f"tradeoff: error: {e}", file=sys.stderr)
        return 2


def _main(args: argparse.Namespace) -> int:
    from voxnero.errors import ConfigError, DataError

    out = Path(args.out)
    if args.repeats < 1 or args.jobs < 1:
        raise ConfigError("--repeats and --jobs must be >= 1")
    note = _machine_note()
    if args.check:
        ref = load_reference(Path(args.check))
        scenes = _scene_map(args.scenes)
        tasks = []
        for r in ref:
            path = scenes.get(r["scene"]) or (Path(r["scene_path"]) if r.get("scene_path")
                                               else None)
            if path is None or not path.is_dir():
                raise DataError(f"scene {r['scene']!r} of the table is not among --scenes",
                                path=args.check, fix=f"pass --scenes .../{r['scene']}")
            pt = Point(r["point"], r["preset"], tuple(r["overrides"].split()))
            tasks += [Task(path, pt, r["stage"], k) for k in range(args.repeats)]
        if args.list:
            for t in tasks:
                print(t.key())
            return 0
        before = {row_key(r) for r in read_csv(out / "tradeoff.csv") if is_done(r)}
        reused = sum(t.key() in before for t in tasks)
        if reused:
            print(f"[tradeoff] --check reuses {reused} finished run(s) already in {out} (an "
                  "interrupted check continues); pass a fresh --out to measure all anew")
        rows = sweep(tasks, out, args.jobs, args.timeout, note=note)
        results = check(ref, summarise(rows), args.tolerance)
        rep = render_check(results, args.tolerance)
        (out / "check.md").write_text(rep)
        print(rep)
        return 0 if all(c.ok for c in results) else 1

    rows: list[dict] = read_csv(out / "tradeoff.csv")
    if args.scenes:
        for s in args.scenes:
            if not Path(s).is_dir():
                raise DataError("no such scene folder", path=s)
        points = resolve_points(args.points, args.base)
        tasks = plan([Path(s).resolve() for s in args.scenes], points, args.stage, args.repeats)
        if args.list:
            for t in tasks:
                print(f"{t.scene.name:20s} {t.stage:9s} #{t.repeat}  {t.point.name:24s} "
                      f"{t.point.config}")
            return 0
        rows = sweep(tasks, out, args.jobs, args.timeout, note=note)
    elif not rows:
        raise ConfigError("nothing to do: no --scenes and no tradeoff.csv in --out",
                          fix="pass --scenes SCENE ... (and --points), or --out of a sweep")
    md = write_outputs(out, rows, note)
    print(md)
    if args.readme:
        update_readme(Path(args.readme), md, out / "tradeoff.png")
        print(f"[tradeoff] updated {args.readme}")
    failed = [r for r in rows if not is_done(r)]
    for r in failed:
        print(f"[tradeoff] {r['scene']} / {r['point']}: {r['status']}", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
