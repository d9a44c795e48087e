"""The ``gyrocal`` command line: one module per command, one error-to-exit-code map."""

from .main import main

__all__ = ["main"]
