"""The ``lfm-studio`` command line.

``lfm-studio`` (or ``lfm-studio gui``) opens the desktop studio; further
sub-commands (simulate, image, info, reconstruct, metrics, bench) run headless.
GUI packages are imported only by the ``gui`` sub-command.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from lfm_studio import __version__
from lfm_studio.cli.bench import add_bench_parser
from lfm_studio.cli.calibrate import add_calibrate_parser
from lfm_studio.cli.console import design_notes, leave_quietly_on_broken_pipe
from lfm_studio.cli.errors import BROKEN_PIPE, EPILOG, INTERRUPTED, exit_code_for
from lfm_studio.cli.info import add_info_parser
from lfm_studio.cli.interrupts import interrupt_message
from lfm_studio.cli.metrics import add_metrics_parser
from lfm_studio.cli.optimize import add_optimize_parsers
from lfm_studio.cli.reconstruct import add_reconstruct_parsers
from lfm_studio.cli.resolution import add_resolution_parser
from lfm_studio.cli.simulate import add_simulate_parsers
from lfm_studio.cli.train import add_train_parser
from lfm_studio.engine.allocator import keep_freed_memory
from lfm_studio.engine.design import list_presets
from lfm_studio.engine.errors import error_text
from lfm_studio.engine.threads import THREADS_VARIABLE, configure_threads
from lfm_studio.ui.app import DEFAULT_PRESET  # a constant: Qt is imported only when the studio starts


def _run_gui(args: argparse.Namespace) -> int:
    from lfm_studio.ui.app import run_studio  # Qt is imported only here

    return run_studio(design=args.design)


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every sub-command."""
    parser = argparse.ArgumentParser(
        prog="lfm-studio",
        description="Design studio for light-field microscopes (simulation, reconstruction, design).",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--version", action="version", version=f"lfm-studio {__version__}")
    parser.add_argument(
        "--threads",
        dest="torch_threads",
        type=int,
        default=None,
        metavar="N",
        help=f"torch CPU threads for the heavy work (default: ${THREADS_VARIABLE}, else the cores idle at "
        "start: this process's cores minus the load average, at least 1; docs/benchmarks.md, thread policy)",
    )
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    gui = sub.add_parser("gui", help="open the desktop studio (default when no command is given)")
    gui.add_argument(
        "design",
        nargs="?",
        default=None,
        help=f"design file (.json) or preset name to open: {', '.join(list_presets())} (default: {DEFAULT_PRESET})",
    )
    gui.set_defaults(handler=_run_gui)
    add_simulate_parsers(sub)
    add_info_parser(sub)
    add_reconstruct_parsers(sub)
    add_metrics_parser(sub)
    add_bench_parser(sub)
    add_resolution_parser(sub)
    add_calibrate_parser(sub)
    add_optimize_parsers(sub)
    add_train_parser(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``lfm-studio`` and ``python -m lfm_studio``; returns the exit status."""
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        # Only options were given (any positional would be the command): they go before "gui".
        args = parser.parse_args([*(argv if argv is not None else sys.argv[1:]), "gui"])
    try:
        with design_notes(args.command):
            configure_threads(args.torch_threads)
            keep_freed_memory()  # per-depth FFT buffers stay in the heap (engine/allocator.py)
            status = int(args.handler(args))
            sys.stdout.flush()  # a closed pipe shows here, not in the interpreter's final flush
            return status
    except BrokenPipeError:  # the reader stopped early (| head): stop quietly
        leave_quietly_on_broken_pipe()
        return BROKEN_PIPE
    except (ValueError, FileNotFoundError, FileExistsError) as error:
        # Named refusals (bad input, output refused, memory, rejected result) without a traceback;
        # the exit code says which kind (EPILOG).
        code = exit_code_for(error)
        if code is None:
            raise
        print(f"lfm-studio {args.command}: error: {error_text(error)}", file=sys.stderr)
        return code
    except (
        KeyboardInterrupt
    ) as interrupt:  # outputs are atomic: none is partial; the message says what was kept
        print(interrupt_message(args.command, interrupt), file=sys.stderr)
        return INTERRUPTED


if __name__ == "__main__":
    sys.exit(main())
