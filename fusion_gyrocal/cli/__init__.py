"""The ``gyrocal`` command line: one module per command, one error-to-exit-code map.

:mod:`.app` holds :func:`main`, the parser and the map (:data:`~.app.ERROR_EXIT_CODES`);
:mod:`.calibrate`, :mod:`.report`, :mod:`.demo`, :mod:`.compare` and :mod:`.fleet` are the commands
(each ``add_parser(subparsers)`` and ``run(args) -> int``); :mod:`.recording` reads the recording
pair; the options' flags come from :mod:`fusion_gyrocal.options`.
"""

from .app import main

__all__ = ["main"]
