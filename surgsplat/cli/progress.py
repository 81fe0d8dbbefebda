"""Rich progress bars shared by the long-running commands."""

from __future__ import annotations

from rich.progress import (BarColumn, MofNCompleteColumn, Progress, TextColumn,
                           TimeElapsedColumn, TimeRemainingColumn)


def progress_bar(*extra_columns: TextColumn) -> Progress:
    """A progress bar: description, bar, n/total, elapsed, remaining, then `extra_columns`."""
    return Progress(TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(),
                    TimeElapsedColumn(), TimeRemainingColumn(), *extra_columns)
