"""Errors that point at the source: ``objectives/x.xml:17: ExecutePolicy: port 'dt' ...``."""
from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class SourceLocation:
    """Where a node was written: file and line (line 0 when unknown)."""

    file: str = "<string>"
    line: int = 0

    def __str__(self) -> str:
        return f"{self.file}:{self.line}" if self.line else self.file


class ObjectiveError(Exception):
    """Bad input: an Objective that cannot be loaded or a value that cannot be used (exit code 2).

    The message always starts with the location, then the node, then what is wrong.
    """

    def __init__(self, what: str, location: SourceLocation | None = None, node: str | None = None) -> None:
        self.what = what
        self.location = location
        self.node = node
        parts = [str(location)] if location else []
        if node:
            parts.append(node)
        parts.append(what)
        super().__init__(": ".join(parts))


class LoadError(ObjectiveError):
    """The XML (or a value in it) is wrong; found while loading, before anything moves."""


class PortError(ObjectiveError):
    """A port value is missing, unknown or of the wrong type."""


class ScriptRunError(ObjectiveError):
    """A script failed while the tree ran: BT.CPP throws there, so the run stops as an error (exit 2).

    Examples: ``=`` to an entry that was never declared, an assignment or a SetBlackboard that
    would change an entry's type, reading an entry nobody wrote. ``script`` is the source text.
    """

    def __init__(self, what: str, location: SourceLocation | None, node: str | None, script: str) -> None:
        self.script = script
        super().__init__(what, location, node)
