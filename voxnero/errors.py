"""User-facing error types.

Raise these for mistakes a user can fix (bad data, bad config). The CLI prints them in one or
two lines without a traceback and exits with code 2. Messages name the file, what is wrong and
what to do about it.
"""

from __future__ import annotations

from pathlib import Path


class VoxneroError(Exception):
    """Base class of errors caused by user input; printed without a traceback."""

    def __init__(self, message: str, path: str | Path | None = None, fix: str | None = None):
        self.path = None if path is None else Path(path)
        self.fix = fix
        parts = []
        if path is not None:
            parts.append(f"{path}: ")
        parts.append(message)
        if fix:
            parts.append(f"\n  fix: {fix}")
        super().__init__("".join(parts))


class DataError(VoxneroError):
    """Input data (images, poses, env maps, meshes) is missing, unreadable or inconsistent."""


class ConfigError(VoxneroError):
    """A preset, config file or key=value override is invalid."""


class NotBuiltError(VoxneroError):
    """A command whose stage is not implemented yet."""


class RunFolderError(VoxneroError):
    """The output folder cannot be used: not a folder, not writable, locked by another run,
    removed during the run, or holding a checkpoint of another scene or other settings."""


class TrainingError(VoxneroError):
    """Training cannot go on: the loss stayed non-finite (a setting or the data is the likely
    cause); the last good checkpoint is kept."""
