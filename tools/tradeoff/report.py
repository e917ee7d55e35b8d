"""``tradeoff.csv`` (every run), its medians, ``tradeoff.md``, ``tradeoff.png``, README block.

The CSV is written by :func:`voxnero.batch.results.write_csv` (atomic, fixed columns) with
floats as ``repr`` so that they read back exactly.
"""

from __future__ import annotations

import csv
import math
import os
import re
import statistics
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from voxnero.batch import results

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


def row_key(row: dict) -> tuple[str, str, str, str, int]:
    """:meth:`Task.key` of a CSV row."""
    return (row["scene"], row["stage"], row["preset"], row["overrides"], int(row["repeat"]))



def read_csv(path: Path) -> list[dict]:
    """Rows of a ``tradeoff.csv`` (values as strings; missing file: no rows)."""
    if not path.is_file():
        return []
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def write_csv(path: Path, rows: Iterable[dict]) -> None:
    """Write rows with :data:`FIELDS` (atomically: a temp file renamed over ``path``)."""
    results.write_csv(path, rows, FIELDS, _fmt_csv)


def _fmt_csv(v: object) -> str:
    """A CSV cell: floats as ``repr`` (exact round trip), NaN as ``nan``, missing empty."""
    if v is None:
        return ""
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


def plot_panels(summaries: Sequence[Summary]) -> list[tuple[str, str]]:
    """The plot's two panels as ``(metric, axis label)``: Chamfer, then the novel-view PSNR
    when any point has one (stage 2), else the normal error (a stage-1 sweep)."""
    has_psnr = any(not math.isnan(s.values.get("psnr", math.nan)) for s in summaries)
    second = (("psnr", "novel-view PSNR dB (higher is better)") if has_psnr
              else ("normal_deg", "normal error ° (lower is better)"))
    return [("chamfer", "Chamfer (lower is better)"), second]


def labelled_points(summaries: Sequence[Summary], metric: str) -> set[tuple[str, str]]:
    """The ``(scene, point)`` pairs whose marker gets the point's name in a panel of ``metric``:
    a non-preset point's name once, at its first scene with a value (a corpus sweep runs the
    same point on ten scenes: ten equal labels piled on each other said nothing more)."""
    seen: set[str] = set()
    out: set[tuple[str, str]] = set()
    for s in summaries:
        v = s.values.get(metric, math.nan)
        if s.is_preset or s.point in seen or math.isnan(v):
            continue
        seen.add(s.point)
        out.add((s.scene, s.point))
    return out


def write_plot(summaries: Sequence[Summary], path: Path, size: tuple[float, float] = (11, 4.5),
               dpi: int = 100) -> None:
    """``tradeoff.png``: time vs Chamfer and time vs PSNR (the normal error for a stage-1
    sweep, :func:`plot_panels`), log time, one marker per scene.

    Presets are large filled markers with their name in bold beside them; other points small,
    hollow, with their name in small grey type beside one of their markers
    (:func:`labelled_points`). The image is ``size × dpi`` pixels exactly
    (1100 × 450 by default).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    markers = ["o", "s", "^", "D", "v", "P", "X", "*"]
    scenes = list(dict.fromkeys(s.scene for s in summaries))
    fig, axes = plt.subplots(1, 2, figsize=size, dpi=dpi)
    for ax, (metric, label) in zip(axes, plot_panels(summaries), strict=True):
        any_pt = False
        named = labelled_points(summaries, metric)
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
                for s in (s for s in others if (s.scene, s.point) in named):
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

