"""The per-scene stage process: a stage's error becomes one line, a failed stage stops the rest.

Stages run in this process here (``voxnero eval`` on missing inputs fails before any heavy
work), so these tests take well under a second.
"""

from __future__ import annotations

import json

from voxnero.batch.child import main, run_stage


def test_user_error_is_one_line(tmp_path):
    rc, err = run_stage(["eval", str(tmp_path / "nomesh"), "--scene", str(tmp_path),
                         "--out", str(tmp_path / "ev")])
    assert rc == 2
    assert "no such run folder or mesh file" in err and str(tmp_path / "nomesh") in err
    assert "\n" not in err


def test_bad_arguments(tmp_path, capsys):
    rc, err = run_stage(["eval", "--no-such-flag"])
    assert rc == 2 and "bad arguments to voxnero eval" in err


def test_spec_stops_at_first_failure(tmp_path):
    status = tmp_path / "status.json"
    bad = ["eval", str(tmp_path / "nomesh"), "--scene", str(tmp_path), "--out", str(tmp_path)]
    spec = tmp_path / "spec.json"
    spec.write_text(json.dumps({"stages": [{"name": "first", "argv": bad},
                                           {"name": "second", "argv": bad}],
                                "status": str(status)}))
    assert main([str(spec)]) == 2
    stages = json.loads(status.read_text())["stages"]
    assert [s["name"] for s in stages] == ["first"]
    assert stages[0]["rc"] == 2 and "no such run folder" in stages[0]["error"]
    assert stages[0]["time_s"] >= 0
