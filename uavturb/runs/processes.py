"""Which process keeps a run: tags naming it (host, pid, the pid's start time) and whether it still
runs, so that a run whose process died (SIGKILL, out of memory) is told from a live one."""

from __future__ import annotations

import os
import socket
from pathlib import Path


def _process_start(pid: int) -> str:
    """Start time of process ``pid`` (clock ticks since boot, Linux), "" where unknown: tells a
    live process from a later one that reuses its pid."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
        return stat.rsplit(")", 1)[1].split()[19]
    except (OSError, IndexError):
        return ""


def process_tags() -> dict[str, str]:
    """Tags ``host``, ``pid`` and ``pid_start`` naming this process as the one keeping a run."""
    pid = os.getpid()
    return {"host": socket.gethostname(), "pid": str(pid), "pid_start": _process_start(pid)}


def process_alive(tags: dict[str, str]) -> bool | None:
    """Whether the process named by a run's :func:`process_tags` still runs: True or False on this
    host, None where that cannot be told (another host, no tags)."""
    if tags.get("host") != socket.gethostname() or not str(tags.get("pid", "")).isdigit():
        return None
    pid = int(tags["pid"])
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass  # exists, another user's
    start = tags.get("pid_start", "")
    return not (start and _process_start(pid) and _process_start(pid) != start)
