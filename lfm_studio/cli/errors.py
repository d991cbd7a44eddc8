"""Exit codes of ``lfm-studio``: one per kind of refusal, documented in ``lfm-studio --help``.

Every refusal prints ``lfm-studio COMMAND: error: MESSAGE`` (what, the value, a fix) on
stderr, without a traceback, and leaves no file behind. A traceback (exit 1) means a bug.
"""

from __future__ import annotations

from lfm_studio.cli import INTERRUPTED
from lfm_studio.engine.io.file_checks import OutputError
from lfm_studio.engine.memory import MemoryBudgetError
from lfm_studio.engine.reconstruct.result_check import ReconstructionRejectedError

BAD_INPUT = 2  # also argparse's code for usage errors
OUTPUT_REFUSED = 3
OUT_OF_MEMORY = 4
RESULT_REJECTED = 5
BROKEN_PIPE = 141  # 128 + SIGPIPE, what a shell reports for a writer whose reader left

#: Exception type -> exit code, most specific first (all are ValueError subclasses but the last ones).
EXIT_CODES: tuple[tuple[type[BaseException], int], ...] = (
    (OutputError, OUTPUT_REFUSED),
    (FileExistsError, OUTPUT_REFUSED),
    (MemoryBudgetError, OUT_OF_MEMORY),
    (ReconstructionRejectedError, RESULT_REJECTED),
    (ValueError, BAD_INPUT),
    (FileNotFoundError, BAD_INPUT),
)

EPILOG = f"""exit status:
  0    success
  {BAD_INPUT}    bad input or usage: an invalid option or value, a design with a missing or
       invalid key, an input file that is missing, truncated, corrupt or does not fit
       (shape, pixel size, dimensionality, complex or NaN/Inf data)
  {OUTPUT_REFUSED}    output refused: it exists (pass --overwrite), it is one of the inputs
       (refused even with --overwrite), or its folder is missing, read-only or full
  {OUT_OF_MEMORY}    not enough memory for the design (checked before allocating)
  {RESULT_REJECTED}    the reconstruction came out all zero, constant or NaN/Inf (not saved)
  {INTERRUPTED}  interrupted (Ctrl+C); the message says what was kept (outputs are whole or
       untouched, never partial) and how to continue (--resume, --overwrite)
  {BROKEN_PIPE}  the output's reader stopped early (e.g. piped into head); the rest was dropped
  1    an unexpected error (a bug: please report the traceback)
Every refusal names the problem and a fix; no refusal leaves a partial file."""


def exit_code_for(error: BaseException) -> int | None:
    """The exit code of a refusal, or None for an unexpected error (let it raise)."""
    for kind, code in EXIT_CODES:
        if isinstance(error, kind):
            return code
    return None
