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
