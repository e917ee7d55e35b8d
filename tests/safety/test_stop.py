"""voxnero/safety/stop.py: Ctrl-C inside a step finishes it, checkpoints and exits 130; the
resumed run is bit-identical to one that was never interrupted (as after SIGTERM)."""

from __future__ import annotations

import os
import signal

import numpy as np

from tests.safety.safety_helpers import blender_scene, run_cli, sdf_of, shape_argv
from voxnero.safety import stop as stop_mod
from voxnero.safety.stop import GracefulStop
from voxnero.shape import trainer as trainer_mod


def test_ctrl_c_inside_a_step_resumes_bit_identically(tmp_path, capsys, monkeypatch):
    """SIGINT used to raise KeyboardInterrupt wherever it landed: the checkpoint held half a
    step (the batch drawn, no update), so the resumed run differed."""
    before = signal.getsignal(signal.SIGINT)  # SIG_IGN when run as a background job
    scene = blender_scene(tmp_path / "scene")
    argv = ("iters=8", "ckpt_every_s=1000")
    rc, _, err = run_cli(shape_argv(scene, tmp_path / "whole", *argv), capsys)
    assert rc == 0, err
    real, calls = trainer_mod.render_rays, {"n": 0}

    def render_rays(*a, **k):  # Ctrl-C in the middle of the 4th training step
        calls["n"] += 1
        if calls["n"] == 4 and k.get("train"):
            os.kill(os.getpid(), signal.SIGINT)
        return real(*a, **k)

    monkeypatch.setattr(trainer_mod, "render_rays", render_rays)
    split = tmp_path / "split"
    rc, stdout, err = run_cli(shape_argv(scene, split, *argv), capsys)
    assert rc == 130 and "stopped at step 4" in stdout, (stdout, err)
    assert not (split / "mesh.ply").exists()
    monkeypatch.setattr(trainer_mod, "render_rays", real)
    rc, stdout, err = run_cli(shape_argv(scene, split, *argv), capsys)
    assert rc == 0 and "at step 4" in stdout, err
    assert np.array_equal(sdf_of(split), sdf_of(tmp_path / "whole"))
    assert signal.getsignal(signal.SIGINT) is before


def test_a_second_signal_stops_at_once_without_a_checkpoint():
    before = signal.getsignal(signal.SIGTERM)
    with GracefulStop() as stop:
        os.kill(os.getpid(), signal.SIGTERM)
        assert stop.flag and not stop.forced and stop.signum == signal.SIGTERM
        try:
            os.kill(os.getpid(), signal.SIGINT)
            raise AssertionError("the second signal did not interrupt")
        except KeyboardInterrupt:
            assert stop.forced
    assert signal.getsignal(signal.SIGTERM) is before


def test_a_repeated_sigterm_is_one_request_unless_it_comes_late(monkeypatch):
    """The kernel's parent-death SIGTERM and a supervisor's arrive together: that must still
    checkpoint at the end of the step. A SIGTERM after REPEAT_S, or a Ctrl-C, forces."""
    with GracefulStop() as stop:
        os.kill(os.getpid(), signal.SIGTERM)
        try:
            os.kill(os.getpid(), signal.SIGTERM)
        except KeyboardInterrupt:  # as a failure, not as pytest's own Ctrl-C
            raise AssertionError("a repeated SIGTERM forced the stop") from None
        assert stop.flag and not stop.forced
        try:
            os.kill(os.getpid(), signal.SIGINT)
            raise AssertionError("Ctrl-C after a SIGTERM did not interrupt")
        except KeyboardInterrupt:
            assert stop.forced
    monkeypatch.setattr(stop_mod, "REPEAT_S", 0.0)
    with GracefulStop() as stop:
        os.kill(os.getpid(), signal.SIGTERM)
        try:
            os.kill(os.getpid(), signal.SIGTERM)
            raise AssertionError("a late second SIGTERM did not interrupt")
        except KeyboardInterrupt:
            assert stop.forced
