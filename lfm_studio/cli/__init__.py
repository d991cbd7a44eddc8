"""The ``lfm-studio`` command line: one module per sub-command, :mod:`.main` assembles them.

``lfm_studio.cli:main`` is the console entry point. GUI packages are imported only by the
``gui`` sub-command.
"""

from lfm_studio.cli.main import build_parser, main

__all__ = ["build_parser", "main"]
