"""Run time against error for every accuracy knob (the table and plot of docs/benchmarks.md).

    python benchmarks/accuracy.py [--design NAME|FILE ...] [--quick] [--out DIR] [--json] [--repeats N]

Same options as ``lfm-studio bench`` (this script only calls it); see
:mod:`lfm_studio.bench` for what is measured and docs/benchmarks.md for the results.
"""

from __future__ import annotations

import argparse
import sys

from lfm_studio.cli.bench import add_bench_parser


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="benchmarks/accuracy.py")
    sub = parser.add_subparsers(dest="command")
    add_bench_parser(sub)
    args = parser.parse_args(["bench", *(sys.argv[1:] if argv is None else argv)])
    return int(args.handler(args))


if __name__ == "__main__":
    sys.exit(main())
