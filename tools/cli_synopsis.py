"""The synopsis at the top of docs/cli.md, generated from the `objective` argument parser (the
engine's commands and the ones this installation adds). ``tests/test_cli.py`` checks that the
page holds exactly this text, so an option added to the parser cannot be missing from the page.

    .venv/bin/python tools/cli_synopsis.py     # print it, to paste into docs/cli.md
"""
from __future__ import annotations

import argparse

from runtime.app.cli import build_parser

WIDTH = 100


def argument_usage(action: argparse.Action) -> str:
    """One argument as the synopsis writes it: ``FILE``, ``FILE...``, ``[--seed SEED]``,
    ``[--set NAME=VALUE ...]``, ``[--live [PORT]]``, ``--out DIR``, ``[--executor local|ray]``."""
    if action.choices is not None and not isinstance(action.choices, dict):
        value = "|".join(str(c) for c in action.choices)
    else:
        value = str(action.metavar or action.dest.upper())  # a str: no metavar here is a tuple
    if not action.option_strings:
        if action.nargs == "+":
            return f"{value}..."
        if action.nargs == "*":
            return f"[{value} ...]"
        return value
    flag = max(action.option_strings, key=len)
    if action.nargs == 0:
        text = flag
    elif action.nargs == "?":
        text = f"{flag} [{value}]"
    elif isinstance(action, argparse._AppendAction):
        text = f"{flag} {value} ..."
    else:
        text = f"{flag} {value}"
    return text if action.required else f"[{text}]"


def command_usage(name: str, parser: argparse.ArgumentParser) -> str:
    """``objective NAME`` and its arguments (positionals first), wrapped at ``WIDTH`` columns; a
    command with actions of its own (``objective client list|start|cancel``) gets a line per action."""
    actions = [a for a in parser._actions if not isinstance(a, argparse._HelpAction) and a.help != argparse.SUPPRESS]
    nested = next((a for a in actions if isinstance(a, argparse._SubParsersAction)), None)
    if nested is not None:
        options = " ".join(argument_usage(a) for a in actions if a.option_strings)
        return "\n".join(command_usage(f"{name} {options} {action}".replace("  ", " "), sub)
                         for action, sub in nested.choices.items())
    parts = [argument_usage(a) for a in actions if not a.option_strings] + [argument_usage(a) for a in actions if a.option_strings]
    head = f"objective {name} "
    lines, line = [], head
    for part in parts:
        if len(line) + len(part) > WIDTH and line.strip() != head.strip():
            lines.append(line.rstrip())
            line = " " * len(head)
        line += part + " "
    lines.append(line.rstrip())
    return "\n".join(lines)


def synopsis() -> str:
    parser = build_parser()
    commands = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    own = [max(a.option_strings, key=len) for a in parser._actions if isinstance(a, argparse._VersionAction)]
    return "\n".join([*(f"objective {flag}" for flag in own),
                      *(command_usage(name, sub) for name, sub in commands.choices.items())])


if __name__ == "__main__":
    print(synopsis())
