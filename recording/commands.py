"""``objective report DIR``: the recording package's command (``objective.commands``)."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from runtime.app.command import EXIT_FAILURE, EXIT_SUCCESS, Command
from runtime.tree.registry import Registry
from runtime.app.terminal import printable


def _add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("dir", type=Path, help="a directory written by `objective run --record DIR`")


def _run(args: argparse.Namespace, registry: Registry) -> int:
    from .report import render_report

    report = render_report(args.dir)
    for path in report.files.values():
        print(path)
    for name, error in report.errors.items():
        print(f"error: {name}: {printable(error)}", file=sys.stderr)
    for reason in report.partial:
        print(f"partial recording: {printable(reason)}", file=sys.stderr)
    return EXIT_FAILURE if report.errors else EXIT_SUCCESS


REPORT = Command(help="render the plots, video, tree and page of a recording again",
                 add_arguments=_add_arguments, run=_run)
