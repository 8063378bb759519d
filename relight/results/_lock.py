"""Output locks (``relight.results`` module docstring, "Locking"): ``.NAME.lock`` next to the folder (it must
survive the swap), held with ``fcntl.flock`` for the whole command; the kernel drops a flock when its
process dies, so a lock left by a dead writer is taken over."""

from __future__ import annotations

import contextlib
import datetime
import errno
import json
import os
import socket
from pathlib import Path

from ._errors import FolderLockedError, _err

__all__ = ["FolderLock"]


def _lock_path(folder: Path) -> Path:
    return folder.parent / f".{folder.name}.lock"


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's live process
        return True
    return True


class FolderLock:
    """An exclusive lock on writing a folder (module docstring, "Locking"); a context manager.

    Args:
        folder: the folder to be written; the lock is ``.NAME.lock`` beside it.
        command: recorded in the lock, for the error a second writer gets.

    ``acquire()`` (or entering the context) raises :class:`FolderLockedError` naming the folder and the
    holder's PID when a live process holds it; a lock left by a dead process is taken over.
    """

    def __init__(self, folder: str | os.PathLike, command: str = "relight"):
        self.folder = Path(folder)
        self.path = _lock_path(self.folder)
        self.command = command
        self._fd: int | None = None

    def acquire(self) -> FolderLock:
        import fcntl

        parent = self.path.parent if str(self.path.parent) else Path(".")
        if not parent.is_dir():
            raise FileNotFoundError(f"{self.folder}: cannot write, folder {parent} does not exist")
        for _ in range(20):
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o666)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = _read_holder(fd)
                os.close(fd)
                raise _err(FolderLockedError, errno.EBUSY,
                           f"{self.folder}: being written by another relight process ({holder}); wait for it to "
                           f"finish or stop it (its lock: {self.path})", self.folder) from None
            except OSError as err:  # no flock here (some network file systems): the PID decides
                if not _take_by_pid(fd, self.folder, self.path, err):
                    continue
            # Whoever held it may have unlinked the file between our open and flock: lock the file on disk.
            try:
                same = os.stat(self.path).st_ino == os.fstat(fd).st_ino
            except FileNotFoundError:
                same = False
            if not same:
                os.close(fd)
                continue
            doc = {"pid": os.getpid(), "host": socket.gethostname(), "command": self.command,
                   "started": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")}
            os.ftruncate(fd, 0)
            os.pwrite(fd, json.dumps(doc).encode(), 0)
            self._fd = fd
            return self
        raise _err(FolderLockedError, errno.EBUSY, f"{self.folder}: could not take its lock {self.path}", self.folder)

    def release(self) -> None:
        if self._fd is None:
            return
        with contextlib.suppress(FileNotFoundError):
            os.unlink(self.path)  # before the close: a waiter re-checks the inode and retries
        os.close(self._fd)
        self._fd = None

    def __enter__(self) -> FolderLock:
        return self.acquire()

    def __exit__(self, *exc) -> None:
        self.release()


def _read_holder(fd: int) -> str:
    try:
        doc = json.loads(os.pread(fd, 4096, 0).decode() or "{}")
        return f"pid {doc['pid']} on {doc.get('host', '?')}, `{doc.get('command', 'relight')}` since {doc['started']}"
    except (ValueError, KeyError, TypeError, UnicodeDecodeError):
        return "pid unknown"


def _take_by_pid(fd: int, folder: Path, path: Path, err: OSError) -> bool:
    """Without flock: refuse if the recorded PID (on this host) is alive, else take the stale lock over."""
    try:
        doc = json.loads(os.pread(fd, 4096, 0).decode() or "{}")
    except (ValueError, UnicodeDecodeError):
        doc = {}
    pid = doc.get("pid")
    if isinstance(pid, int) and pid != os.getpid() and doc.get("host") == socket.gethostname() and _pid_alive(pid):
        os.close(fd)
        raise _err(FolderLockedError, errno.EBUSY, f"{folder}: being written by another relight process (pid {pid}); "
                                                   f"wait for it to finish or stop it (its lock: {path}; flock: {err})",
                   folder) from None
    return True
