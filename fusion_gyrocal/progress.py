"""The one progress bar of long work (compare's Monte Carlo, the fleet, the report): rich, on stderr.

It costs nothing to throughput: it is advanced once per unit of work (a run, a device, a stage), never per
sample, and disabled (no output at all) where nobody watches (not a terminal, ``enabled=False``).
"""

from __future__ import annotations

import sys


def progress_bar(enabled: bool | None = None):
    """A transient rich progress bar (description, bar, done/total, time left).

    ``enabled=None``: shown when stderr is a terminal. Use as a context manager; ``add_task`` / ``advance``
    as in :class:`rich.progress.Progress`.
    """
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    if enabled is None:
        enabled = sys.stderr.isatty()
    return Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
                    disable=not enabled, transient=True)
