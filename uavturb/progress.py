"""Progress bars that read well on a terminal and in a log file (tqdm).

On a terminal: tqdm's bar, redrawn in place (``\\r``) at most twice a second. Anywhere else (a file,
a pipe, a CI log): the same tqdm status written as whole lines, one every :data:`FILE_INTERVAL`
seconds and one at the end, so logs hold short lines rather than one line of thousands of
characters. Every long loop of the package reports through :func:`progress_bar`.
"""

from __future__ import annotations

import sys
from typing import IO, Any

from tqdm import tqdm

#: seconds between two status lines when the stream is not a terminal
FILE_INTERVAL = 10.0
#: the status without a drawn bar, for log files
FILE_FORMAT = "{desc}: {n_fmt}/{total_fmt} {unit} ({percentage:.0f} %), elapsed {elapsed}, left {remaining}{postfix}"


class _Lines:
    """A stream wrapper that turns tqdm's in-place redraws into whole lines."""

    def __init__(self, stream: IO[str]):
        self.stream = stream

    def write(self, text: str) -> None:
        line = text.replace("\r", "").strip()
        if line:
            self.stream.write(line + "\n")

    def flush(self) -> None:
        self.stream.flush()


def is_terminal(stream: IO[str] | None = None) -> bool:
    stream = stream if stream is not None else sys.stderr
    return bool(getattr(stream, "isatty", lambda: False)())


def progress_bar(total: int | None, desc: str, unit: str = "it", *, stream: IO[str] | None = None,
                 **kwargs: Any) -> tqdm:
    """A tqdm bar on ``stream`` (default stderr) that behaves on a terminal and in a file.

    Parameters
    ----------
    total : number of items (None: unknown)
    desc : what is counted, e.g. ``"generate sim (quick)"``
    unit : the items' unit, e.g. ``"trajectories"``
    kwargs : passed to :class:`tqdm.tqdm`

    Returns
    -------
    The bar: ``update(n)``, ``set_postfix_str(text)``, ``close()`` (or use it as a context manager).
    """
    stream = stream if stream is not None else sys.stderr
    if is_terminal(stream):
        return tqdm(total=total, desc=desc, unit=unit, file=stream, mininterval=0.5, dynamic_ncols=True, **kwargs)
    return tqdm(total=total, desc=desc, unit=unit, file=_Lines(stream), mininterval=FILE_INTERVAL, ncols=200,
                bar_format=FILE_FORMAT if total else "{desc}: {n_fmt} {unit}, elapsed {elapsed}{postfix}", **kwargs)


def show_rate(bar: tqdm, count: int, what: str) -> None:
    """Show a second count beside the items (``"6274 samples, 669 samples/s"``) at the bar's next refresh."""
    elapsed = max(bar.format_dict.get("elapsed", 0.0), 1e-9)
    bar.set_postfix_str(f"{count} {what}, {count / elapsed:.0f} {what}/s", refresh=False)


class Stages:
    """A progress bar over the named stages of one command, for work that is a few long steps rather than
    many short items (``uavturb gap``: reading, aligning, selecting effects, ...).

    Call it with a stage's name as that stage starts: the stages before it count as done and its name shows
    beside the bar. The bar is cleared when closed: on a terminal it leaves no trace, in a log file the
    status lines written while the work ran (one every :data:`FILE_INTERVAL` seconds) stay, so a short
    command prints nothing and a failure's one line stays the only one.

    Parameters
    ----------
    desc : the command, e.g. ``"uavturb gap"``
    names : the stages in the order they run
    stream : where to write (default stderr)
    """

    def __init__(self, desc: str, names: list[str], stream: IO[str] | None = None):
        self.names = list(names)
        self.terminal = is_terminal(stream)
        # in a log, the first line comes after FILE_INTERVAL, like every later one; on a terminal no rate
        # (stages are not alike: "1.6 s/stages" says nothing)
        extra = {"bar_format": "{desc}: {percentage:3.0f}%|{bar}| {n_fmt}/{total_fmt} stages [{elapsed}{postfix}]"} \
            if self.terminal else {"delay": FILE_INTERVAL}
        self.bar = progress_bar(len(self.names), desc, "stages", stream=stream, leave=False, **extra)

    def __call__(self, name: str) -> None:
        """Stage ``name`` (one of ``names``) starts."""
        self.bar.set_postfix_str(name, refresh=False)
        self.bar.update(self.names.index(name) - self.bar.n)
        if self.terminal:  # a few stages: each is drawn as it starts
            self.bar.refresh()

    def close(self) -> None:
        self.bar.close()

    def __enter__(self) -> "Stages":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
