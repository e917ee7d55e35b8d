"""Configuration of ``voxnero batch``: the ``batch:`` section of a preset.

Every key can be overridden on the command line with the ``batch.`` prefix
(``voxnero batch scenes/ --preset standard --out runs/ batch.num_gpus=1``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Literal

from voxnero.config import Range, at_least
from voxnero.errors import ConfigError


@dataclass
class BatchConfig:
    """Ray resources and fault tolerance of one scene's task."""

    RANGES: ClassVar[dict[str, Range]] = {
        "num_cpus": Range(0.0, 1e6), "num_gpus": Range(0.0, 1e6), "memory_mb": at_least(0),
        "max_retries": at_least(0, 1000), "lock_timeout_s": Range(0.0), "local_cpus": at_least(0),
        "object_store_mb": at_least(1)}
    """Allowed values (:func:`voxnero.config.check_numbers`), checked before ``validate``."""

    num_cpus: float = 1.0
    """CPUs Ray reserves for one scene's task (the stages use ``shape.threads`` threads)."""
    num_gpus: float = 0.0
    """GPUs Ray reserves for one scene's task; > 0 on a GPU cluster (the task then runs on CUDA,
    the stages pick ``--device auto``)."""
    memory_mb: int = 0
    """Memory Ray reserves for one scene's task (0 = no reservation); set it from the peak
    memory column of a previous ``results.csv`` so that a node never runs more scenes than fit."""
    max_retries: int = 3
    """Ray re-runs a scene whose worker (or stage process) died this many times; each retry
    resumes from the scene's last checkpoint."""
    command: Literal["reconstruct", "shape"] = "reconstruct"
    """What runs per scene: ``reconstruct`` (stage 1 + stage 2) or ``shape`` (stage 1 only)."""
    eval: bool = True
    """Run ``voxnero eval`` on the stage-1 mesh when the scene has ground truth (``gt/``)."""
    lock_timeout_s: float = 600.0
    """How long a retried task waits for the previous attempt's stage process to stop."""
    local_cpus: int = 0
    """CPUs of a local Ray (without ``--address``); 0 = all cores of this machine."""
    object_store_mb: int = 150
    """Object store of a local Ray (``ray.init`` without ``--address``); the tasks pass only
    paths and small dicts, so little is needed."""
    dashboard: bool = False
    """Start the dashboard of a local Ray: it serves the state API (``ray.util.state``,
    ``ray list tasks``) to watch or debug the workers, at the cost of ~12 more processes
    (~1.2 GB RSS summed here). A cluster started with ``ray start --head`` has it by default."""

    def validate(self) -> None:
        """Check what ``RANGES`` cannot (single values are checked before); raise
        :class:`ConfigError` with the fix."""
        if self.num_cpus <= 0 and self.num_gpus <= 0:
            raise ConfigError("batch.num_cpus and batch.num_gpus are both 0",
                              fix="a scene's task needs at least batch.num_cpus > 0")
