"""File locks shared by the processes of this host that use one MLflow store: creating the store
(:func:`store_lock`) and a sweep's parent and children (:func:`named_lock`). They live in a cache
folder (:func:`lock_folder`), never in the user's working directory."""

from __future__ import annotations

import contextlib
import hashlib
import os
import tempfile
from pathlib import Path
from typing import Iterator

from filelock import FileLock, Timeout

from uavturb.errors import UavturbError


class LockTimeout(UavturbError):
    """Another process has held a store's lock for too long (one line naming the lock file)."""


def sqlite_path(uri: str) -> Path | None:
    """The database file of a ``sqlite:///`` URI (relative to the working directory), else None."""
    if not uri.startswith("sqlite:///"):
        return None
    path = uri[len("sqlite:///"):].split("?", 1)[0]
    return Path(path) if path and path != ":memory:" else None


#: seconds a process waits for another one creating the store before giving up
LOCK_TIMEOUT_S = 600.0


def lock_folder(uri: str) -> Path:
    """The folder of the file locks of a store: ``$XDG_CACHE_HOME/uavturb/locks/<store>`` (default
    ``~/.cache``), one per store (a SQLite file by its absolute path, a server by its URI), shared
    by the processes of this host. Never the working directory: the user's folder keeps only
    what they asked for."""
    db = sqlite_path(uri)
    name = str(db.resolve()) if db is not None else uri
    cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    folder = cache / "uavturb" / "locks" / hashlib.sha1(name.encode()).hexdigest()[:16]
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:  # no writable home: the temporary directory
        folder = Path(tempfile.gettempdir()) / f"uavturb-locks-{os.getuid()}" / folder.name
        folder.mkdir(parents=True, exist_ok=True)
    return folder


@contextlib.contextmanager
def store_lock(uri: str) -> Iterator[None]:
    """Exclusive lock on a SQLite store (file ``store.lock`` in :func:`lock_folder`); nothing for other stores."""
    db = sqlite_path(uri)
    if db is None:
        yield
        return
    db.parent.mkdir(parents=True, exist_ok=True)
    lock = FileLock(str(lock_folder(uri) / "store.lock"))
    try:
        lock.acquire(timeout=LOCK_TIMEOUT_S)
    except Timeout:
        raise LockTimeout(f"MLflow store {uri}: another process has held {lock.lock_file} for "
                         f"{LOCK_TIMEOUT_S:.0f} s; if none is running, delete that file") from None
    try:
        yield
    finally:
        lock.release()


def named_lock(name: str, uri: str) -> FileLock:
    """A :class:`filelock.FileLock` named ``name`` for the store ``uri``, shared by the processes of
    this host (a sweep's parent and children), in :func:`lock_folder`."""
    safe = "".join(c if c.isalnum() or c in "-_." else "_" for c in name)
    return FileLock(str(lock_folder(uri) / f"{safe}.lock"))
