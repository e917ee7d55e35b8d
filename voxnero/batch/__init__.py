"""``voxnero batch``: reconstruct many scenes as Ray tasks (one task per scene).

* :mod:`voxnero.batch.config` — the ``batch:`` section of a preset (Ray resources, retries);
* :mod:`voxnero.batch.manifest` — which scenes: a folder of scene folders or a YAML/CSV list;
* :mod:`voxnero.batch.child` — the per-scene process that runs the stage commands in-process;
* :mod:`voxnero.batch.tasks` — the per-scene Ray task (skip if done, run the child, result);
* :mod:`voxnero.batch.runner` — the driver (local Ray or ``--address``, progress, retries);
* :mod:`voxnero.batch.results` — ``results.csv`` / ``results.md``.
* :mod:`voxnero.batch.process` — a command as a measured child (exit code, wall time, peak RSS;
  also ``tools/tradeoff``'s runner).

Ray is imported only by :mod:`voxnero.batch.runner` (and lazily by :mod:`voxnero.batch.tasks`).
"""
