"""What a benchmark reads of a process's memory (Linux's ``/proc``; None or 0 elsewhere): its own, in the measured
process (light on purpose: it is imported before the imports it measures), or a child's, from outside it."""

from __future__ import annotations

import os


def status_kib(key: str, pid: int | str = "self") -> int | None:
    """Process ``pid``'s (this one's by default) ``VmHWM`` (peak) or ``VmRSS`` (now) [KiB]; None where ``/proc``
    does not say."""
    try:
        with open(f"/proc/{pid}/status") as f:
            return int(f.read().split(key + ":")[1].split()[0])
    except (OSError, IndexError, ValueError):
        return None


def children_private_kib(pid: int | str = "self") -> int:
    """The pages process ``pid``'s (this one's by default) children hold of their own [KiB]: ``Private_Clean`` +
    ``Private_Dirty`` of each child's ``/proc/<child>/smaps_rollup`` (what a forked child wrote or allocated, not what
    it shares with its parent); 0 without children or ``/proc``."""
    total = 0
    try:
        tasks = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return 0
    for task in tasks:
        try:
            with open(f"/proc/{pid}/task/{task}/children") as f:
                pids = f.read().split()
        except OSError:
            continue
        for child in pids:
            try:
                with open(f"/proc/{child}/smaps_rollup") as f:
                    total += sum(int(line.split()[1]) for line in f
                                 if line.startswith(("Private_Clean:", "Private_Dirty:")))
            except OSError:  # a child that ended meanwhile
                pass
    return total
