"""The project's errors: one root, with the user's mistakes and the project's own bugs apart.

- ``ObjectiveRuntimeError``: the root of every error the project raises on purpose.
- ``ObjectiveError``: a mistake the user can fix: bad input (an Objective, a port value, a file,
  an option, a message a peer sent) or a setup the robot does not match (an unknown frame, a
  missing service). The run ends as ERROR (exit 2) with a message that points at the source:
  ``objectives/x.xml:17: ExecutePolicy: port 'dt' ...``. Each module's own error classes
  (``ChunkError``, ``FrameError``, ...) derive from it.
- ``InternalError``: a broken promise inside the project, a bug. It is reported as an internal
  error whose message points at the crash report, never as the user's mistake; so is any
  exception that is not an ``ObjectiveRuntimeError``.
"""
from __future__ import annotations

import difflib
from dataclasses import dataclass
from typing import Iterable, TypeVar


@dataclass(frozen=True)
class SourceLocation:
    """Where a node was written: file and line (line 0 when unknown)."""

    file: str = "<string>"
    line: int = 0

    def __str__(self) -> str:
        return f"{self.file}:{self.line}" if self.line else self.file


MAX_NAMED_CALLS = 4
"""The most SubTree calls an error's message names one by one (``inside_subtree``)."""


class ObjectiveRuntimeError(Exception):
    """The root of every error the project raises on purpose (see the module's docstring).

    The message starts with the location, then the node, then what is wrong; a module's own
    subclass raised with one sentence (``ChunkError("chunk has no points")``) is just that sentence.
    """

    callers: tuple[tuple[SourceLocation, str], ...] = ()
    """The SubTree calls the node is inside, outermost first: (where the call is written, the SubTree's ID)."""
    also: tuple[ObjectiveRuntimeError, ...] = ()
    """Errors found with this one (the node's other ports, its children), reported after it."""

    def __init__(self, what: str, location: SourceLocation | None = None, node: str | None = None) -> None:
        self.what = what
        self.location = location
        self.node = node
        super().__init__(_message(what, location, node))

    def at(self: E, location: SourceLocation | None, node: str | None) -> E:
        """This error, raised without a place, placed at ``node`` written at ``location``."""
        self.location, self.node = location, node
        self.args = (_message(self.what, location, node),)
        return self

    def inside_subtree(self: E, caller: SourceLocation, subtree: str) -> E:
        """This error with the SubTree call its node is inside named first, where the user wrote it:
        ``caller.xml:7: SubTree 'Move to Waypoint': objectives/move_to_waypoint.xml:18: ...``.
        Of a chain longer than ``MAX_NAMED_CALLS`` the outermost two calls and the innermost one
        are named, the others counted."""
        if not self.callers:
            self._inside = self.args[0]
        self.callers = ((caller, subtree), *self.callers)
        calls = [f"{where}: SubTree '{tree}'" for where, tree in self.callers]
        if len(calls) > MAX_NAMED_CALLS:
            calls = [*calls[:2], f"({len(calls) - 3} more SubTree calls)", calls[-1]]
        self.args = (": ".join([*calls, self._inside]),)
        return self

    def within(self: E, where: str) -> E:
        """This error with ``where`` it happened said first: ``world 'vla_sim': <error>``."""
        self.args = (f"{where}: {self.args[0]}",)
        return self


E = TypeVar("E", bound=ObjectiveRuntimeError)


def _message(what: str, location: SourceLocation | None, node: str | None) -> str:
    return ": ".join([*([str(location)] if location else []), *([node] if node else []), what])


class ObjectiveError(ObjectiveRuntimeError):
    """A mistake of the user: bad input or a setup the robot does not match (exit code 2)."""


INTERNAL = "internal"


def error_kind(error: BaseException) -> str:
    """What kind of error ended a run, for grouping: a user error's class name (``SetupError``,
    ``PortError``, ...), or ``internal`` for a bug."""
    return type(error).__name__ if isinstance(error, ObjectiveError) else INTERNAL


class InternalError(ObjectiveRuntimeError):
    """A bug: an unexpected exception told in one paragraph (``runtime.tree.crash.describe_crash``),
    naming the crash report that holds its traceback."""


class SetupError(ObjectiveError):
    """The Objective asks for something this robot or cell does not have: an unknown frame, object,
    joint or waypoint, a service or action that is not there or has another type, paired ports of
    different lengths. Raised while the tree runs, it ends the run as ERROR at once: no
    RetryUntilSuccessful or Fallback repeats it (BT.CPP throws out of the tick the same way)."""


class OptionError(ObjectiveError, ValueError):
    """An option the user gave (of a world, a policy backend, a command) that cannot be used."""


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


def did_you_mean(word: str, candidates: Iterable[str]) -> str:
    """``"; did you mean 'a' or 'b'?"`` for the candidates close to ``word``, or ``""``."""
    close = difflib.get_close_matches(word, sorted(set(candidates)), n=3, cutoff=0.6)
    if not close:
        return ""
    quoted = [f"'{c}'" for c in close]
    options = quoted[0] if len(quoted) == 1 else ", ".join(quoted[:-1]) + " or " + quoted[-1]
    return f"; did you mean {options}?"
