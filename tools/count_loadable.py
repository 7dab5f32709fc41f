"""Count how many Objectives under a directory load here (what ``objective validate`` checks).

    .venv/bin/python tools/count_loadable.py /path/to/moveit_pro_example_ws/src [--list] [--json]

Every ``*.xml`` in a directory named ``objectives`` (at any depth) is one Objective. Each is
validated like ``objective validate FILE --path ITS_DIRECTORY``: SubTrees resolve from the file,
then this project's ``objectives/`` library, then the Objective's own directory (MoveIt Pro
configs keep their SubTrees next to the Objectives that use them). Prints the count, and which
first errors stop the others, grouped by the node they name (the most common first).
"""
from __future__ import annotations

import argparse
import collections
import json
import re
import sys
from dataclasses import dataclass
from pathlib import Path

from runtime.errors import ObjectiveError
from runtime.tree.loader import validate
from runtime.tree.registry import Registry

_UNKNOWN = re.compile(r"unknown node '([^']+)'|undefined SubTree '([^']+)'")


@dataclass(frozen=True)
class Outcome:
    file: Path
    error: str | None

    @property
    def loads(self) -> bool:
        return self.error is None

    @property
    def blocker(self) -> str:
        """What the error is about: the missing node or SubTree, else the error's last part."""
        if self.error is None:
            return ""
        m = _UNKNOWN.search(self.error)
        if m:
            return f"missing: {m.group(1) or m.group(2)}"
        return "other: " + self.error.rsplit(": ", 1)[-1][:80]


def objective_files(root: Path) -> list[Path]:
    return sorted(p for p in root.rglob("*.xml") if p.parent.name == "objectives")


def check(file: Path, registry: Registry, objectives_dir: Path | None = None) -> Outcome:
    try:
        validate(file, registry, search_paths=[file.parent], objectives_dir=objectives_dir).trees_or_raise()
    except ObjectiveError as err:
        return Outcome(file, str(err))
    except Exception as err:  # a loader bug must not hide the other files' answers
        return Outcome(file, f"internal error: {type(err).__name__}: {err}")
    return Outcome(file, None)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("root", type=Path, help="directory searched for objectives/*.xml")
    parser.add_argument("--list", action="store_true", help="print each file's outcome")
    parser.add_argument("--json", action="store_true", help="print a JSON summary instead of text")
    parser.add_argument("--objectives-dir", type=Path, default=None, metavar="DIR",
                        help="the SubTree library searched first (default: this project's objectives/)")
    args = parser.parse_args(argv)
    if not args.root.is_dir():
        print(f"error: {args.root} is not a directory", file=sys.stderr)
        return 2
    registry = Registry.from_entry_points()
    outcomes = [check(f, registry, args.objectives_dir) for f in objective_files(args.root)]
    loaded = sum(o.loads for o in outcomes)
    blockers = collections.Counter(o.blocker for o in outcomes if not o.loads)
    if args.json:
        print(json.dumps({
            "objectives": len(outcomes),
            "load": loaded,
            "first_errors": dict(blockers.most_common()),
            "files": {str(o.file.relative_to(args.root)): o.error or "ok" for o in outcomes},
        }, indent=2))
        return 0
    if args.list:
        for o in outcomes:
            print(f"{'ok ' if o.loads else 'ERR'} {o.file.relative_to(args.root)}" + ("" if o.loads else f"\n      {o.error}"))
    print(f"{loaded} of {len(outcomes)} Objectives load")
    for blocker, count in blockers.most_common():
        print(f"{count:5d}  {blocker}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
