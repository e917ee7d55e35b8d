"""The speed-accuracy trade of VoxNeRO's presets and knobs (``python -m tools.tradeoff``).

* :mod:`tools.tradeoff.points` — what a point is: a preset plus ``key=value`` overrides;
* :mod:`tools.tradeoff.runner` — the runs: training command(s) and ``voxnero eval`` as measured
  child processes (:mod:`voxnero.batch.process`), resumed from the CSV;
* :mod:`tools.tradeoff.report` — ``tradeoff.csv``, the medians, ``tradeoff.md``,
  ``tradeoff.png`` and the table between a README's markers;
* :mod:`tools.tradeoff.check` — ``--check``: an earlier table re-run and compared;
* :mod:`tools.tradeoff.cli` — the command line (its help text describes the tool).
"""

from tools.tradeoff.check import (
    CHECKED,
    CheckResult,
    check,
    compare,
    load_reference,
    render_check,
)
from tools.tradeoff.cli import STAGES, _machine_note, main
from tools.tradeoff.points import (
    DEFAULT_SPEC,
    REPO,
    Point,
    load_spec,
    parse_point,
    points_for_stage,
    resolve_points,
)
from tools.tradeoff.report import (
    FIELDS,
    MARK_BEGIN,
    MARK_END,
    METRICS,
    Summary,
    _num,
    is_done,
    labelled_points,
    merge_rows,
    parse_markdown,
    plot_panels,
    read_csv,
    render_markdown,
    replace_between_markers,
    row_key,
    summarise,
    update_readme,
    write_csv,
    write_outputs,
    write_plot,
)
from tools.tradeoff.runner import (
    ChildResult,
    Runner,
    Task,
    _slug,
    child_env,
    kill_children,
    plan,
    run_child,
    sweep,
)

__all__ = [
    "CHECKED", "DEFAULT_SPEC", "FIELDS", "MARK_BEGIN", "MARK_END", "METRICS", "REPO", "STAGES",
    "CheckResult", "ChildResult", "Point", "Runner", "Summary", "Task", "_machine_note", "_num",
    "_slug", "check", "child_env", "compare", "is_done", "kill_children", "labelled_points",
    "load_reference", "load_spec", "main", "merge_rows", "parse_markdown", "parse_point", "plan",
    "plot_panels", "points_for_stage", "read_csv", "render_check", "render_markdown",
    "replace_between_markers",
    "resolve_points", "row_key", "run_child", "summarise", "sweep", "update_readme", "write_csv",
    "write_outputs", "write_plot",
]
