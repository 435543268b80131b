"""What a benchmark's child process reads of its own memory (Linux's ``/proc``; None or 0 elsewhere). Light on
purpose: it is imported before the imports it measures."""

from __future__ import annotations

import os


def status_kib(key: str) -> int | None:
    """This process's ``VmHWM`` (peak) or ``VmRSS`` (now) [KiB]; None where ``/proc`` does not say."""
    try:
        with open("/proc/self/status") as f:
            return int(f.read().split(key + ":")[1].split()[0])
    except (OSError, IndexError, ValueError):
        return None


def children_private_kib() -> int:
    """The pages this process's children hold of their own [KiB]: ``Private_Clean`` + ``Private_Dirty`` of each
    child's ``/proc/<pid>/smaps_rollup`` (what a forked child wrote or allocated, not what it shares with its
    parent); 0 without children or ``/proc``."""
    total = 0
    try:
        tasks = os.listdir("/proc/self/task")
    except OSError:
        return 0
    for task in tasks:
        try:
            with open(f"/proc/self/task/{task}/children") as f:
                pids = f.read().split()
        except OSError:
            continue
        for pid in pids:
            try:
                with open(f"/proc/{pid}/smaps_rollup") as f:
                    total += sum(int(line.split()[1]) for line in f
                                 if line.startswith(("Private_Clean:", "Private_Dirty:")))
            except OSError:  # a child that ended meanwhile
                pass
    return total
