"""Exceptions that the CLI reports as one line, without a traceback."""

from pathlib import Path


class SurgsplatError(Exception):
    """A user-facing error: bad input, bad option, missing file. Its message says what to fix."""


class DataError(SurgsplatError):
    """A file or folder on disk is missing, unreadable or not what was expected."""

    def __init__(self, path: str | Path, problem: str):
        self.path = Path(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")

    def __reduce__(self):
        """Pickled as (path, problem), so it crosses process boundaries (Ray tasks)."""
        return type(self), (self.path, self.problem)


def os_error_line(err: OSError) -> str:
    """`<path>: <what>` for an OSError (the path when it names one)."""
    what = err.strerror or str(err)
    if err.filename is not None and err.filename2 is not None:
        return f"{err.filename} -> {err.filename2}: {what}"
    return f"{err.filename}: {what}" if err.filename is not None else what
