"""Read the parts of an SRDF the planning scene uses: groups, disabled collisions, end effectors.

The SRDF is MoveIt's semantic description (``<group>`` with ``<joint>``, ``<chain>``,
``<link>`` and ``<group>`` members, ``<disable_collisions>``, ``<end_effector>``,
``<group_state>``). Parsing is pure: names are checked against a model later, by
``RobotModel``, so errors can say both where in the file and what the model has.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from lxml import etree

from runtime.errors import ObjectiveError


class SrdfError(ObjectiveError, ValueError):
    """A malformed SRDF; the message names the file and line."""


@dataclass(frozen=True)
class SrdfGroup:
    name: str
    joints: tuple[str, ...] = ()
    links: tuple[str, ...] = ()
    chains: tuple[tuple[str, str], ...] = ()
    """``(base_link, tip_link)`` pairs."""
    subgroups: tuple[str, ...] = ()
    line: int = 0


@dataclass(frozen=True)
class EndEffector:
    name: str
    group: str
    parent_link: str
    parent_group: str | None = None


@dataclass(frozen=True)
class DisabledPair:
    link1: str
    link2: str
    reason: str = ""

    @property
    def key(self) -> frozenset[str]:
        return frozenset((self.link1, self.link2))


@dataclass(frozen=True)
class Srdf:
    robot_name: str
    source: str
    groups: dict[str, SrdfGroup] = field(default_factory=dict)
    disabled_collisions: tuple[DisabledPair, ...] = ()
    end_effectors: tuple[EndEffector, ...] = ()
    group_states: dict[tuple[str, str], dict[str, float]] = field(default_factory=dict)
    """``(group, state name) -> {joint: value}``."""

    def disabled_keys(self) -> frozenset[frozenset[str]]:
        return frozenset(pair.key for pair in self.disabled_collisions)


_PARSER = etree.XMLParser(resolve_entities=False, no_network=True, remove_comments=True)


def _required(element: etree._Element, attribute: str, where: str) -> str:
    value: str | None = element.get(attribute)
    if not value:
        raise SrdfError(f"{where}:{element.sourceline}: <{element.tag}> needs a {attribute!r} attribute")
    return value


def parse_srdf(source: str | os.PathLike[str]) -> Srdf:
    """Parse an SRDF file path or XML text."""
    text = str(source)
    if text.lstrip().startswith("<"):
        where = "<srdf string>"
        root = etree.fromstring(text.encode(), _PARSER)
    else:
        where = str(Path(text))
        try:
            root = etree.parse(where, _PARSER).getroot()
        except OSError as exc:
            raise SrdfError(f"cannot read SRDF {where}: {exc}") from exc
        except etree.XMLSyntaxError as exc:
            raise SrdfError(f"{where}: not well-formed XML: {exc}") from exc
    if root.tag != "robot":
        raise SrdfError(f"{where}:{root.sourceline}: SRDF root must be <robot>, found <{root.tag}>")

    groups: dict[str, SrdfGroup] = {}
    for g in root.iterfind("group"):
        name = _required(g, "name", where)
        if name in groups:
            raise SrdfError(f"{where}:{g.sourceline}: group {name!r} defined twice")
        groups[name] = SrdfGroup(
            name=name,
            joints=tuple(_required(e, "name", where) for e in g.iterfind("joint")),
            links=tuple(_required(e, "name", where) for e in g.iterfind("link")),
            chains=tuple((_required(e, "base_link", where), _required(e, "tip_link", where)) for e in g.iterfind("chain")),
            subgroups=tuple(_required(e, "name", where) for e in g.iterfind("group")),
            line=g.sourceline or 0,
        )
    for group in groups.values():
        for sub in group.subgroups:
            if sub not in groups:
                raise SrdfError(f"{where}:{group.line}: group {group.name!r} includes unknown group {sub!r}")

    disabled = tuple(
        DisabledPair(_required(e, "link1", where), _required(e, "link2", where), e.get("reason", ""))
        for e in root.iterfind("disable_collisions")
    )
    end_effectors = tuple(
        EndEffector(
            name=_required(e, "name", where),
            group=_required(e, "group", where),
            parent_link=_required(e, "parent_link", where),
            parent_group=e.get("parent_group"),
        )
        for e in root.iterfind("end_effector")
    )
    states: dict[tuple[str, str], dict[str, float]] = {}
    for s in root.iterfind("group_state"):
        values = {}
        for j in s.iterfind("joint"):
            raw = _required(j, "value", where)
            try:
                values[_required(j, "name", where)] = float(raw.split()[0])
            except ValueError:
                raise SrdfError(f"{where}:{j.sourceline}: joint value {raw!r} is not a number") from None
        states[(_required(s, "group", where), _required(s, "name", where))] = values
    return Srdf(
        robot_name=root.get("name", ""),
        source=where,
        groups=groups,
        disabled_collisions=disabled,
        end_effectors=end_effectors,
        group_states=states,
    )
