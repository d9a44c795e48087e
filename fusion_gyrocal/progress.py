"""The one progress bar of long work (compare's Monte Carlo, the fleet, the report): rich, on stderr.

It costs nothing to throughput: it is advanced once per unit of work (a run, a device, a stage), never per
sample, and disabled (no output at all) where nobody watches (not a terminal, ``enabled=False``).
"""

from __future__ import annotations

import sys


class _NoBar:
    """The bar where nobody watches: the calls of :class:`rich.progress.Progress` that do nothing (and no
    import of ``rich.progress``, about 0.05 s of a command's start)."""

    def __enter__(self):
        return self

    def __exit__(self, *exc) -> bool:
        return False

    def add_task(self, *args, **kwargs) -> int:
        return 0

    def advance(self, *args, **kwargs) -> None:
        return None

    def update(self, *args, **kwargs) -> None:
        return None


def progress_bar(enabled: bool | None = None):
    """A transient rich progress bar (description, bar, done/total, time left).

    ``enabled=None``: shown when stderr is a terminal. Use as a context manager; ``add_task`` / ``advance`` /
    ``update`` as in :class:`rich.progress.Progress` (disabled: an object whose calls do nothing).
    """
    if enabled is None:
        enabled = sys.stderr.isatty()
    if not enabled:
        return _NoBar()
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

    return Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeRemainingColumn(),
                    transient=True)
