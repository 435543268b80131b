"""What tests of forked work read of other processes."""

from __future__ import annotations

import time
from pathlib import Path


def pid_written(path: Path, timeout_s: float = 5.0) -> int:
    """The pid a child writes to ``path`` as it starts, waited for up to ``timeout_s``."""
    for _ in range(int(timeout_s / 0.01)):
        if path.exists() and path.read_text():
            break
        time.sleep(0.01)
    return int(path.read_text())


def process_gone(pid: int, timeout_s: float = 5.0) -> bool:
    """Whether the process ``pid`` has exited (or exits within ``timeout_s``): gone, or a zombie not yet reaped."""
    for _ in range(int(timeout_s / 0.01)):
        try:
            if Path(f"/proc/{pid}/stat").read_text().split(")")[-1].split()[0] in ("Z", "X"):
                return True
        except (FileNotFoundError, ProcessLookupError):  # reaped, even between the open and the read
            return True
        time.sleep(0.01)
    return False
