"""Errors that reach the user as one line, never as a traceback."""

from __future__ import annotations

from pathlib import Path


class UavturbError(Exception):
    """An error the command line reports as one line and a non-zero exit status."""


class InputError(UavturbError):
    """Bad input: names the file (or config key) and the problem.

    Parameters
    ----------
    where : str or Path
        The file, folder or config key at fault.
    problem : str
        What is wrong with it, in words a user can act on.
    """

    def __init__(self, where: str | Path, problem: str):
        self.where = str(where)
        self.problem = problem
        super().__init__(f"{self.where}: {problem}")
