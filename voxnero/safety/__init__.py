"""Run folders and the training loops' safety nets (issue 23: nothing lost, nothing silent).

* :mod:`voxnero.safety.folder` — the output folder of one command run: checked usable, locked
  against a second run, outputs staged and moved in only when the run succeeded;
* :mod:`voxnero.safety.fingerprint` — what a checkpoint was made from (scene, mesh, settings),
  so that a resume with something else is refused;
* :mod:`voxnero.safety.stop` — Ctrl-C and SIGTERM finish the current step, then checkpoint;
* :mod:`voxnero.safety.guard` — a loss that stays non-finite stops the run; NaN state is never
  checkpointed.
"""
