"""Atomic publishing of output folders and files: the one rule every writing command follows.

The rule (users' data is never lost):

- ``--out`` may name a folder that does not exist (its parents are created), an empty folder,
  or a folder that uavturb wrote itself, recognised by its marker file :data:`MARKER`, which
  lists the files it wrote. Replacing such a folder needs ``overwrite``. A file output
  (``residuals --out``, ``gap --apply``, ``compare``'s tables) that exists is replaced only
  with ``overwrite``.
- Nothing uavturb did not write is ever deleted: a folder without the marker (the current
  directory, a checkout, a user's notes), or a marked folder that now also holds files uavturb
  did not write, is refused with one line naming it. The check is repeated at the moment of
  replacing, on the folder as it is then; a folder or file that did not exist when the command
  started and exists when it ends (a user's, or a second command's with the same ``--out``)
  is never replaced: the later writer is refused.
- The new content is built in a hidden temporary folder beside ``out`` and renamed into place
  only when complete, so ``out`` holds a complete result or the previous one, never half of
  either; a failure leaves no temporary folder behind, and the temporary folders of a killed
  command (their names carry the host and process id) are removed by the next command that
  writes to the same place.
- ``--out .`` (or any folder holding the working directory) is refused up front: a folder
  cannot be replaced while it is in use.
- A place that cannot be written (read-only folder, a file where a folder is expected) is
  named in one line (:class:`~uavturb.errors.InputError`), never a traceback.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import hashlib
import json
import os
import re
import shutil
import socket
import tempfile
import time
from pathlib import Path
from typing import Iterator, Sequence

from uavturb.errors import InputError

MARKER = ".uavturb-output.json"
OVERWRITE_HINT = " (use --overwrite to replace it)"


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


# --- temporary names: ours, and whose ----------------------------------------------------------

def _owner() -> str:
    """``<host hash>-<pid>``: temporary names carry it so a later command knows whose they are."""
    host = hashlib.sha1(socket.gethostname().encode()).hexdigest()[:8]
    return f"{host}-{os.getpid()}"


def _temp_pattern(name: str) -> re.Pattern[str]:
    """Names of the temporary entries of ``name`` (``.NAME.HOST-PID.XXXXXXXX<suffix>``)."""
    return re.compile(rf"^\.{re.escape(name)}\.([0-9a-f]{{8}})-(\d+)\.[a-z0-9_]{{8}}(\.tmp|\.old|\.part)$")


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:  # EPERM: it exists, under another user
        return True
    return True


def clean_stale(target: Path) -> list[Path]:
    """Remove the temporary entries beside ``target`` that a killed command of this host left;
    returns them. A ``.old`` folder whose content was never put back (the command was killed
    between moving the old result away and putting the new one in place) is restored first; one
    that holds anything uavturb did not write is left where it is."""
    host = _owner().split("-")[0]
    pattern = _temp_pattern(target.name)
    removed = []
    try:
        entries = list(target.parent.iterdir())
    except OSError:
        return removed
    for entry in entries:
        m = pattern.match(entry.name)
        if m is None or m.group(1) != host or _pid_alive(int(m.group(2))):
            continue
        kept = entry / target.name
        if m.group(3) == ".old" and kept.is_dir() and not target.exists():
            with contextlib.suppress(OSError):
                _rename_noreplace(kept, target)
        if m.group(3) == ".old" and kept.is_dir() and any(kept.iterdir()) and _foreign(kept) is not None:
            continue
        if entry.is_dir() and not entry.is_symlink():
            shutil.rmtree(entry, ignore_errors=True)
        else:
            with contextlib.suppress(OSError):
                entry.unlink()
        removed.append(entry)
    return removed


def _temp_folder(target: Path, suffix: str) -> Path:
    tmp = Path(tempfile.mkdtemp(prefix=f".{target.name}.{_owner()}.", suffix=suffix, dir=target.parent))
    usual_mode(tmp)
    return tmp


# --- renaming without replacing --------------------------------------------------------------

_RENAME_NOREPLACE = 1
_AT_FDCWD = -100


def _renameat2() -> object | None:
    try:
        fn = ctypes.CDLL(None, use_errno=True).renameat2
    except (AttributeError, OSError):
        return None
    fn.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
    return fn


_RENAMEAT2 = _renameat2()


def _rename_noreplace(src: Path, dst: Path) -> None:
    """Rename ``src`` to ``dst`` only if ``dst`` does not exist (not even as an empty folder):
    ``FileExistsError`` otherwise. Atomic where the system has ``renameat2(RENAME_NOREPLACE)``."""
    if _RENAMEAT2 is not None:
        if _RENAMEAT2(_AT_FDCWD, os.fsencode(src), _AT_FDCWD, os.fsencode(dst), _RENAME_NOREPLACE) == 0:
            return
        err = ctypes.get_errno()
        if err not in (errno.EINVAL, errno.ENOSYS, errno.EOPNOTSUPP):  # else: this file system lacks it
            raise OSError(err, os.strerror(err), str(dst))
    if os.path.lexists(dst):
        raise FileExistsError(errno.EEXIST, os.strerror(errno.EEXIST), str(dst))
    os.rename(src, dst)


# --- folders ----------------------------------------------------------------------------------

def _holds_working_directory(out: Path) -> bool:
    cwd = Path.cwd().resolve()
    target = out.resolve()
    return target == cwd or target in cwd.parents


def _foreign(out: Path) -> str | None:
    """Why ``out`` (an existing, non-empty folder) may not be replaced, or None when it may."""
    ours = _written_by_us(out)
    if ours is None:
        return "exists, is not empty and was not written by uavturb; nothing in it is touched: choose a new folder"
    foreign = [f for f in _files_below(out) if f != MARKER and f not in ours]
    if foreign:
        return (f"holds {foreign[0][:200]!r}, which uavturb did not write; move it away or choose a new folder "
                "(nothing was deleted)")
    return None


def check_output_folder(out: str | Path, *, overwrite: bool, hint: str = OVERWRITE_HINT) -> Path:
    """Check, before any work, that ``out`` may receive a result; returns it as a Path.

    Raises
    ------
    InputError : ``out`` is a file; or is the working directory or holds it; or exists, is not
        empty and was not written by uavturb; or was written by uavturb but ``overwrite`` is
        false; or holds files uavturb did not write; or its nearest existing parent cannot be written.
    """
    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(out, "exists and is not a folder")
    if out.name in ("", ".", "..") or _holds_working_directory(out):
        raise InputError(out, "is the working folder (or holds it); an output folder is replaced as a whole: "
                              "name a new folder, e.g. --out ./results")
    if out.is_dir() and any(out.iterdir()):
        why = _foreign(out)
        if why is not None:
            raise InputError(out, why)
        if not overwrite:
            raise InputError(out, f"already exists{hint}")
    _existing_parent(out)
    if out.is_dir() and not os.access(out, os.W_OK | os.X_OK):
        raise InputError(out, "is not writable")
    return out


def check_apart(out: str | Path, inputs: Sequence[str | Path], *, what: str = "--out") -> None:
    """Refuse an output that would replace or enter an input: ``out`` (a folder replaced as a whole, or a file)
    may not be an input, hold one, or lie inside an input folder (``uavturb gap REC --out REC --overwrite`` once
    replaced the recording it had just read with its report).

    Raises
    ------
    InputError : ``<out>: is the input ...``, naming the input and ``what`` (the option that named ``out``)
    """
    target = Path(out).resolve()
    for given in inputs:
        source = Path(given).resolve()
        if target == source:
            why = "is an input of this command"
        elif source.is_relative_to(target):
            why = f"holds an input of this command ({given})"
        elif source.is_dir() and target.is_relative_to(source):
            why = f"lies inside an input of this command ({given})"
        else:
            continue
        raise InputError(out, f"{why}: {what} would replace or change it; name a folder or file elsewhere")


@contextlib.contextmanager
def publish_folder(out: str | Path, *, overwrite: bool, command: str, hint: str = OVERWRITE_HINT) -> Iterator[Path]:
    """Yield an empty temporary folder; when the block ends normally it becomes ``out``.

    ``out`` is checked by :func:`check_output_folder` first (call that earlier too, before long
    work, so that a bad ``--out`` fails at once). The published folder carries :data:`MARKER`,
    which names ``command`` and lists what it wrote. On an exception nothing changes at ``out``
    and the temporary folder is removed. What ``out`` was at this check decides how it is
    replaced (:func:`_put_in_place`): a folder that appears meanwhile is never replaced.
    """
    out = check_output_folder(out, overwrite=overwrite, hint=hint)
    before = "absent" if not out.exists() else "ours" if any(out.iterdir()) else "empty"
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        clean_stale(out)
        tmp = _temp_folder(out, ".tmp")
    except OSError as e:
        raise InputError(out.parent, f"cannot create the output here ({e.strerror or e})") from None
    try:
        yield tmp
        marker = {"command": command, "written": time.strftime("%Y-%m-%dT%H:%M:%S%z"), "files": _files_below(tmp)}
        (tmp / MARKER).write_text(json.dumps(marker, indent=1))
        _put_in_place(tmp, out, before)
    except OSError as e:
        raise InputError(out, f"cannot be written ({e.strerror or e})") from None
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _put_in_place(tmp: Path, out: Path, before: str) -> None:
    """Rename ``tmp`` to ``out``, as ``out`` was at the start (``before``): ``"ours"``, a folder
    of ours, is checked again once moved aside (no file uavturb did not write may have appeared
    in it); ``"empty"`` is replaced only while it is still empty; ``"absent"`` is never replaced."""
    changed = "changed while this command ran"
    if before != "ours":
        try:
            if before == "empty":
                os.rename(tmp, out)  # the system replaces only a folder that is still empty
            else:
                _rename_noreplace(tmp, out)
        except OSError as e:
            if e.errno in (errno.EEXIST, errno.ENOTEMPTY, errno.ENOTDIR, errno.EISDIR):
                raise InputError(out, "was created or filled while this command ran (by you or another uavturb "
                                      "command); it is not replaced and this result was not kept") from None
            raise
        return
    trash = _temp_folder(out, ".old")
    old = trash / out.name
    try:
        os.rename(out, old)
    except FileNotFoundError:
        shutil.rmtree(trash, ignore_errors=True)
        raise InputError(out, f"{changed} (it was removed); this result was not kept") from None
    why = _foreign(old) if any(old.iterdir()) else None
    if why is not None:
        _rename_noreplace(old, out)
        shutil.rmtree(trash, ignore_errors=True)
        raise InputError(out, f"{changed}: {why}")
    try:
        _rename_noreplace(tmp, out)
    except FileExistsError:
        raise InputError(out, f"{changed} (created again); the previous result is kept in {old}") from None
    shutil.rmtree(trash, ignore_errors=True)


@contextlib.contextmanager
def atomic_folder(folder: str | Path) -> Iterator[Path]:
    """Yield a temporary folder beside ``folder``; when the block ends normally it becomes
    ``folder`` (replacing an older one, :func:`replace_folder`), otherwise it is removed:
    ``folder`` is never half-written. For folders inside a project-owned tree (trajectories,
    chunks); user-named outputs go through :func:`publish_folder`."""
    folder = Path(folder)
    folder.parent.mkdir(parents=True, exist_ok=True)
    tmp = _temp_folder(folder, ".tmp")  # no clean_stale: called once per item of large trees
    try:
        yield tmp
        replace_folder(tmp, folder)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def replace_folder(tmp: Path, folder: Path) -> None:
    """Put the complete folder ``tmp`` under the name ``folder`` (replacing an older one): at no
    moment does ``folder`` hold a half-written or half-deleted tree."""
    if folder.exists():
        trash = _temp_folder(folder, ".old")
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


# --- files ------------------------------------------------------------------------------------

def check_output_file(path: str | Path, *, overwrite: bool, hint: str = OVERWRITE_HINT) -> Path:
    """Check, before any work, that the file ``path`` may be written: it must not exist unless
    ``overwrite`` (and then be a file); its nearest existing parent must be a writable folder.

    Raises
    ------
    InputError : naming ``path`` or the parent at fault.
    """
    path = Path(path)
    if path.is_dir():
        raise InputError(path, "is a folder, not a file")
    if os.path.lexists(path) and not overwrite:
        raise InputError(path, f"already exists{hint}")
    _existing_parent(path)
    return path


def _existing_parent(path: Path) -> Path:
    """The nearest existing folder above ``path`` (where the output will be created), checked to be a
    writable folder."""
    parent = path.absolute().parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise InputError(parent, "is not a folder: cannot create the output below it")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise InputError(parent, "is not writable")
    return parent


def write_text_atomic(path: str | Path, text: str, *, overwrite: bool = True, hint: str = OVERWRITE_HINT) -> Path:
    """Write ``text`` to ``path`` through a temporary file in the same folder and a rename
    (parents created; see :func:`publish_file` for ``overwrite``)."""
    with publish_file(path, overwrite=overwrite, hint=hint) as tmp:
        tmp.write_text(text)
    return Path(path)


@contextlib.contextmanager
def publish_file(path: str | Path, *, overwrite: bool = True, hint: str = OVERWRITE_HINT) -> Iterator[Path]:
    """Yield a temporary file name beside ``path``; when the block ends normally it becomes
    ``path`` (parents created). Nothing is left behind on failure.

    ``overwrite`` false (every file a user names): an existing ``path`` is refused, and one that
    appears while the block runs is not replaced either (the rename does not replace). Files of
    uavturb's own trees (manifests) pass ``overwrite`` true.
    """
    path = check_output_file(path, overwrite=overwrite, hint=hint)
    existed = os.path.lexists(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        clean_stale(path)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.{_owner()}.", suffix=".part", dir=path.parent)
        os.close(fd)
    except OSError as e:
        raise InputError(path, f"cannot be written ({e.strerror or e})") from None
    try:
        yield Path(tmp)
        usual_mode(Path(tmp))
        if existed:
            os.replace(tmp, path)
        else:
            try:
                _rename_noreplace(Path(tmp), path)
            except FileExistsError:
                raise InputError(path, "was created while this command ran (by you or another uavturb command); "
                                       "it is not replaced and this result was not kept") from None
    except OSError as e:
        raise InputError(path, f"cannot be written ({e.strerror or e})") from None
    finally:
        Path(tmp).unlink(missing_ok=True)
