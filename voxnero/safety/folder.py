"""The output folder of one command run (``--out``): usable, locked, written only on success.

Every command that writes a folder opens it with :class:`RunFolder`::

    with RunFolder(args.out, "material", fresh=STATE if args.fresh else None) as run:
        save_resolved(run.staging, ...)        # config.yaml, staged
        ... train (checkpoints in run.path), write outputs into run.staging ...
        run.commit()                           # outputs and config.yaml move in, one by one

* **usable**: ``--out`` an existing file, a path under a file or a folder that cannot be
  written is a :class:`~voxnero.errors.RunFolderError` naming the path (exit 2, no traceback);
* **locked**: ``.voxnero.lock`` holds an exclusive ``flock`` for the run and records its pid,
  host, command and start time. A second run into the folder is refused with that record. A lock
  nobody holds is stale (its process died, on this host or another sharing the folder: the kernel
  or the file server drops the ``flock`` with the process) and is taken over with a note; on a
  filesystem without ``flock`` the record decides (same host and pid not running: stale);
* **atomic**: outputs and ``config.yaml`` are written into ``run.staging`` (``.partial/``
  inside the folder, so on the same filesystem) and moved in with :func:`os.replace` by
  :meth:`RunFolder.commit`; a run that fails before it leaves a good folder as it was (run state
  such as checkpoints stays in the folder itself);
* **removed mid-run**: an error after the folder (or its lock) vanished becomes one
  :class:`~voxnero.errors.RunFolderError` naming the folder.
"""

from __future__ import annotations

import errno
import fcntl
import json
import os
import shutil
import socket
import time
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any

from voxnero.errors import RunFolderError

LOCK = ".voxnero.lock"
"""Lock file of a run folder."""
STAGING = ".partial"
"""Sub-folder where a run's outputs wait until it succeeded."""
FIX_OUT = "pass another --out"


def atomic_write_text(path: str | Path, text: str) -> Path:
    """Write ``text`` to ``path`` through a temporary file beside it and :func:`os.replace`:
    a reader sees the old file or the new one, never a part."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        tmp.write_text(text)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)
    return path


def _file_above(path: Path) -> Path | None:
    """The first existing non-folder among ``path``'s ancestors (or ``path`` itself)."""
    for p in [path, *path.parents]:
        if p.exists() or p.is_symlink():
            return None if p.is_dir() else p
    return None


def usable_folder(path: str | Path) -> Path:
    """Create ``path`` as a folder if needed and check that it can be written.

    Raises:
        RunFolderError: an existing file, a path under a file, no permission (naming the path).
    """
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise RunFolderError("--out is an existing file, not a folder", path=p,
                             fix=f"{FIX_OUT} (a new or existing folder; the file is left alone)")
    try:
        p.mkdir(parents=True, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        above = _file_above(p)
        raise RunFolderError(f"cannot create the output folder: {above or 'a parent'} is a file",
                             path=p, fix=FIX_OUT) from None
    except PermissionError:
        raise RunFolderError("cannot create the output folder: permission denied", path=p,
                             fix=f"{FIX_OUT} (a folder you may write)") from None
    except OSError as e:
        raise RunFolderError(f"cannot create the output folder: {e.strerror}", path=p,
                             fix=FIX_OUT) from None
    return p


def pid_alive(pid: int) -> bool:
    """Whether a process ``pid`` runs on this host."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process
        return True
    return True


def _describe(rec: dict[str, Any]) -> str:
    when = rec.get("started")
    since = time.strftime(" since %Y-%m-%d %H:%M:%S", time.localtime(when)) \
        if isinstance(when, (int, float)) else ""
    return (f"voxnero {rec.get('command', '?')} (pid {rec.get('pid', '?')} on host "
            f"{rec.get('host', '?')}{since})")


class RunFolder:
    """One command run's output folder: checked, locked, outputs committed on success.

    Args:
        path: the ``--out`` folder (created).
        command: command name, recorded in the lock.
        fresh: with ``--fresh``, the run-state entries (files or folders, e.g.
            ``checkpoint.pt``) deleted once the lock is held, so that the run starts over;
            None keeps them (a re-run resumes).
        log: where notes go (a stale lock taken over, a fresh start).
    """

    def __init__(self, path: str | Path, command: str, fresh: Iterable[str] | None = None,
                 log: Callable[[str], None] = print):
        self.path = Path(path)
        self.command = command
        self.fresh = None if fresh is None else list(fresh)
        self.log = log
        self.fd = -1
        self.created = False
        self.stale: dict[str, Any] | None = None
        """The record of a stale lock taken over, if any."""

    # ------------------------------------------------------------------ paths
    @property
    def lock_path(self) -> Path:
        return self.path / LOCK

    @property
    def staging(self) -> Path:
        """Folder for outputs until :meth:`commit` (same filesystem as the run folder)."""
        return self.path / STAGING

    # ------------------------------------------------------------------ lock
    def _record(self) -> dict[str, Any]:
        return {"pid": os.getpid(), "host": socket.gethostname(), "command": self.command,
                "started": time.time()}

    @staticmethod
    def _read(fd: int) -> dict[str, Any]:
        try:
            data = os.pread(fd, 65536, 0)
            rec = json.loads(data.decode()) if data.strip() else {}
        except (OSError, ValueError, UnicodeDecodeError):
            return {}
        return rec if isinstance(rec, dict) else {}

    def _refuse(self, holder: dict[str, Any], unsure: bool = False) -> RunFolderError:
        msg = f"another run holds this folder: {_describe(holder)}"
        fix = "wait for it to end (or stop it), or pass another --out"
        if unsure:
            fix += f"; if no such run is going on, delete {self.lock_path}"
        return RunFolderError(msg, path=self.path, fix=fix)

    def _open_lock(self) -> int:
        try:
            return os.open(self.lock_path, os.O_RDWR | os.O_CREAT, 0o644)
        except PermissionError:
            raise RunFolderError("the output folder is not writable", path=self.path,
                                 fix=f"{FIX_OUT} (a folder you may write)") from None
        except OSError as e:
            raise RunFolderError(f"cannot write in the output folder: {e.strerror}",
                                 path=self.path, fix=FIX_OUT) from None

    def _acquire(self) -> None:
        me = self._record()
        for _ in range(5):
            fd = self._open_lock()
            holder: dict[str, Any] = {}
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = self._read(fd)
                os.close(fd)
                raise self._refuse(holder) from None
            except OSError as e:  # no flock on this filesystem: judge by the record
                if e.errno not in (errno.ENOLCK, errno.EOPNOTSUPP, errno.EINVAL):
                    os.close(fd)
                    raise
                holder = self._read(fd)
                if holder and holder.get("pid") != me["pid"]:
                    if holder.get("host") != me["host"]:
                        os.close(fd)
                        raise self._refuse(holder, unsure=True) from None
                    if pid_alive(int(holder.get("pid", -1))):
                        os.close(fd)
                        raise self._refuse(holder) from None
            try:  # the file we locked is still the lock (another run may have removed it)
                same = os.fstat(fd).st_ino == os.stat(self.lock_path).st_ino
            except FileNotFoundError:
                same = False
            if not same:
                os.close(fd)
                continue
            holder = holder or self._read(fd)
            if holder:
                self.stale = holder
                self.log(f"[{self.command}] note: took over the stale lock of {_describe(holder)}"
                         f": it no longer runs")
            data = json.dumps(me).encode()
            os.ftruncate(fd, 0)
            os.pwrite(fd, data, 0)
            os.fsync(fd)
            self.fd = fd
            return
        raise RunFolderError("the lock file keeps changing: another run is starting here",
                             path=self.path, fix="start one run at a time, or pass another --out")

    def _release(self) -> None:
        if self.fd < 0:
            return
        try:
            if self.alive():
                self.lock_path.unlink(missing_ok=True)
        finally:
            os.close(self.fd)
            self.fd = -1

    def alive(self) -> bool:
        """Whether the folder and this run's lock file are still there."""
        try:
            return os.stat(self.lock_path).st_ino == os.fstat(self.fd).st_ino
        except OSError:
            return False

    def check(self) -> None:
        """Raise if the folder was removed (or its lock replaced) since the run began.

        Raises:
            RunFolderError: naming the folder.
        """
        if not self.alive():
            raise self.removed_error()

    def removed_error(self) -> RunFolderError:
        return RunFolderError("the output folder was removed (or its lock file deleted) "
                              "during the run; nothing more is written", path=self.path,
                              fix="re-run the command (into this --out it starts over)")

    # ------------------------------------------------------------------ outputs
    def commit(self) -> list[Path]:
        """Move every staged output into the folder (:func:`os.replace`, file by file, at the
        same relative path); returns the final paths.

        Raises:
            RunFolderError: the folder was removed during the run.
        """
        self.check()
        moved = []
        if self.staging.is_dir():
            for src in sorted(p for p in self.staging.rglob("*") if not p.is_dir()):
                dest = self.path / src.relative_to(self.staging)
                dest.parent.mkdir(parents=True, exist_ok=True)
                os.replace(src, dest)
                moved.append(dest)
            shutil.rmtree(self.staging, ignore_errors=True)
        return moved

    # ------------------------------------------------------------------ context
    def __enter__(self) -> RunFolder:
        existed = self.path.is_dir()
        usable_folder(self.path)
        self.created = not existed
        try:
            self._acquire()
        except BaseException:
            self._remove_if_empty()
            raise
        shutil.rmtree(self.staging, ignore_errors=True)  # left by a killed run
        self.staging.mkdir()
        if self.fresh:
            gone = []
            for name in self.fresh:
                p = self.path / name
                if p.is_dir() and not p.is_symlink():
                    shutil.rmtree(p)
                    gone.append(name)
                elif p.exists() or p.is_symlink():
                    p.unlink()
                    gone.append(name)
            if gone:
                self.log(f"[{self.command}] --fresh: removed {', '.join(gone)} from {self.path}")
        return self

    def _remove_if_empty(self) -> None:
        if self.created:
            try:
                self.path.rmdir()
            except OSError:
                pass

    def __exit__(self, exc_type, exc, tb) -> None:
        removed = exc is not None and not isinstance(exc, RunFolderError) and not self.alive()
        shutil.rmtree(self.staging, ignore_errors=True)
        self._release()
        if exc is not None:
            self._remove_if_empty()
        if removed:
            raise self.removed_error() from None
