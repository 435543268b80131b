"""A progress line on stderr for long generators."""

from __future__ import annotations

import sys
import time


class Progress:
    """A progress line on stderr: items done, samples, samples/s and ETA (from the items' pace)."""

    def __init__(self, label: str, total_items: int, stream=None, every: float = 0.5):
        self.label, self.total_items = label, total_items
        self.items, self.samples = 0, 0
        self.t0 = time.perf_counter()
        self.stream = stream if stream is not None else sys.stderr
        self.tty = hasattr(self.stream, "isatty") and self.stream.isatty()
        self.every = every if self.tty else 5.0
        self.last = 0.0

    def update(self, items: int, samples: int) -> None:
        self.items += items
        self.samples += samples
        now = time.perf_counter()
        if now - self.last >= self.every or self.items >= self.total_items:
            self.last = now
            self._print(now)

    def rate(self) -> float:
        """Samples per second since the start."""
        return self.samples / max(time.perf_counter() - self.t0, 1e-9)

    def _print(self, now: float) -> None:
        elapsed = now - self.t0
        left = self.total_items - self.items
        eta = elapsed / self.items * left if self.items else float("nan")
        line = (f"{self.label}: {self.items}/{self.total_items}, {self.samples} samples, "
                f"{self.rate():.0f} samples/s, elapsed {elapsed:.0f} s, ETA {eta:.0f} s")
        print(("\r" + line) if self.tty else line, end="" if self.tty else "\n", file=self.stream, flush=True)

    def close(self) -> None:
        if self.tty and self.items:
            print(file=self.stream, flush=True)
