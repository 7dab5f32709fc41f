"""A subcommand of ``objective`` that a package adds, and the exit codes every command uses."""
from __future__ import annotations

import argparse
from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable

if TYPE_CHECKING:  # stdlib only at run time: runtime.app.build_interfaces runs before anything else works
    from runtime.tree.registry import Registry

EXIT_SUCCESS, EXIT_FAILURE, EXIT_BAD_INPUT = 0, 1, 2
COMMAND_GROUP = "objective.commands"
OBJECTIVE_FILE_HELP = "the Objective: a BehaviorTree.CPP v4 XML file"
POLICY_SPECS = "oracle, replay:FILE, lerobot:DIR, FILE.py:FACTORY, MODULE:FACTORY, http(s)://HOST:PORT or none"
"""Every form ``--policy SPEC`` takes (``policy.specs`` parses them), for the commands' help."""
POLICY_HELP = (f"the policy the world serves on /get_action_chunk in headless runs: {POLICY_SPECS} (default oracle; "
               "an inference server's bearer key from POLICY_SERVER_KEY)")


@dataclass(frozen=True)
class Command:
    """A subcommand a package adds by naming it in the ``objective.commands`` entry-point group
    (the entry point's name is the command's name).

    ``add_arguments`` fills the command's parser; ``run(args, registry)`` returns the exit code
    (0 success, 1 failure, 2 bad input). Keep the module that defines it light: every
    ``objective`` invocation loads it to build ``--help``; import heavy things inside ``run``.
    """

    help: str
    add_arguments: Callable[[argparse.ArgumentParser], None]
    run: Callable[[argparse.Namespace, "Registry"], int]
    needs_registry: bool = True
    """False for a command that works before the behaviors can load (``build-interfaces``, which
    builds what they import): ``run`` gets None instead of the registry."""
