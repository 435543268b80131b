"""Atomic publishing of output folders and files: the one rule every writing command follows.

The rule (users' data is never lost):

- ``--out`` may name a folder that does not exist (its parents are created), an empty folder,
  or a folder that uavturb wrote itself, recognised by its marker file :data:`MARKER`, which
  lists the files it wrote. Replacing such a folder needs ``overwrite``.
- Nothing uavturb did not write is ever deleted: a folder without the marker (the current
  directory, a checkout, a user's notes), or a marked folder that now also holds files uavturb
  did not write, is refused with one line naming it.
- The new content is built in a hidden temporary folder beside ``out`` and renamed into place
  only when complete, so ``out`` holds a complete result or the previous one, never half of
  either; a failure leaves no temporary folder behind.
- A place that cannot be written (read-only folder, a file where a folder is expected) is
  named in one line (:class:`~uavturb.errors.InputError`), never a traceback.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import tempfile
import time
from pathlib import Path
from typing import Iterator

from uavturb.errors import InputError

MARKER = ".uavturb-output.json"


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def usual_mode(path: Path) -> None:
    """``tempfile`` makes private (0700/0600) entries; give them the modes of ordinary ones."""
    base = 0o777 if path.is_dir() else 0o666
    os.chmod(path, base & ~_umask())


def _files_below(folder: Path) -> list[str]:
    """Every file and folder below ``folder``, as sorted POSIX paths relative to it."""
    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*"))


def _written_by_us(folder: Path) -> set[str] | None:
    """The entries the marker of ``folder`` lists, or None where it has no readable marker."""
    try:
        body = json.loads((folder / MARKER).read_text())
        return set(body["files"])
    except (OSError, ValueError, KeyError, TypeError):
        return None


def check_output_folder(out: str | Path, *, overwrite: bool, hint: str = " (use --overwrite to replace it)") -> Path:
    """Check, before any work, that ``out`` may receive a result; returns it as a Path.

    Raises
    ------
    InputError : ``out`` is a file; or exists, is not empty and was not written by uavturb; or
        was written by uavturb but ``overwrite`` is false; or holds files uavturb did not write;
        or its nearest existing parent cannot be written.
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(out, "exists and is not a folder")
    if out.is_dir() and any(out.iterdir()):
        ours = _written_by_us(out)
        if ours is None:
            raise InputError(out, "exists, is not empty and was not written by uavturb; nothing in it is "
                                  "touched: choose a new folder")
        foreign = [f for f in _files_below(out) if f != MARKER and f not in ours]
        if foreign:
            raise InputError(out, f"holds {foreign[0]!r}, which uavturb did not write; move it away or "
                                  "choose a new folder (nothing was deleted)")
        if not overwrite:
            raise InputError(out, f"already exists{hint}")
    parent = out.absolute().parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise InputError(parent, "is not a folder: cannot create the output below it")
    if not os.access(parent, os.W_OK | os.X_OK) or (out.is_dir() and not os.access(out, os.W_OK | os.X_OK)):
        raise InputError(parent if not out.is_dir() else out, "is not writable")
    return out


@contextlib.contextmanager
def publish_folder(out: str | Path, *, overwrite: bool, command: str,
                   hint: str = " (use --overwrite to replace it)") -> Iterator[Path]:
    """Yield an empty temporary folder; when the block ends normally it becomes ``out``.

    ``out`` is checked by :func:`check_output_folder` first (call that earlier too, before long
    work, so that a bad ``--out`` fails at once). The published folder carries :data:`MARKER`,
    which names ``command`` and lists what it wrote. On an exception nothing changes at ``out``
    and the temporary folder is removed.
    """
    out = check_output_folder(out, overwrite=overwrite, hint=hint)
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", suffix=".tmp", dir=out.parent))
    except OSError as e:
        raise InputError(out.parent, f"cannot create the output here ({e.strerror or e})") from None
    usual_mode(tmp)
    try:
        yield tmp
        marker = {"command": command, "written": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "files": _files_below(tmp)}
        (tmp / MARKER).write_text(json.dumps(marker, indent=1))
        replace_folder(tmp, out)
    except OSError as e:
        raise InputError(out, f"cannot be written ({e.strerror or e})") from None
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


@contextlib.contextmanager
def atomic_folder(folder: str | Path) -> Iterator[Path]:
    """Yield a temporary folder beside ``folder``; when the block ends normally it becomes
    ``folder`` (replacing an older one, :func:`replace_folder`), otherwise it is removed:
    ``folder`` is never half-written. For folders inside a project-owned tree (trajectories,
    chunks); user-named outputs go through :func:`publish_folder`."""
    folder = Path(folder)
    folder.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", suffix=".tmp", dir=folder.parent))
    usual_mode(tmp)
    try:
        yield tmp
        replace_folder(tmp, folder)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def replace_folder(tmp: Path, folder: Path) -> None:
    """Put the complete folder ``tmp`` under the name ``folder`` (replacing an older one): at no
    moment does ``folder`` hold a half-written or half-deleted tree."""
    if folder.exists():
        trash = Path(tempfile.mkdtemp(prefix=f".{folder.name}.", suffix=".old", dir=folder.parent))
        os.replace(folder, trash / folder.name)
        try:
            os.replace(tmp, folder)
        except BaseException:
            os.replace(trash / folder.name, folder)
            raise
        finally:
            shutil.rmtree(trash, ignore_errors=True)
    else:
        os.replace(tmp, folder)


def write_text_atomic(path: str | Path, text: str) -> Path:
    """Write ``text`` to ``path`` through a temporary file in the same folder and a rename
    (parents created; an unwritable place is one :class:`InputError` line)."""
    with publish_file(path) as tmp:
        tmp.write_text(text)
    return Path(path)


@contextlib.contextmanager
def publish_file(path: str | Path) -> Iterator[Path]:
    """Yield a temporary file name beside ``path``; when the block ends normally it replaces
    ``path`` (parents created). Nothing is left behind on failure."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=path.suffix or ".tmp", dir=path.parent)
        os.close(fd)
    except OSError as e:
        raise InputError(path, f"cannot be written ({e.strerror or e})") from None
    try:
        yield Path(tmp)
        usual_mode(Path(tmp))
        os.replace(tmp, path)
    except OSError as e:
        raise InputError(path, f"cannot be written ({e.strerror or e})") from None
    finally:
        Path(tmp).unlink(missing_ok=True)
