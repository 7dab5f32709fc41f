"""``tree.svg``: the tree with each node coloured by the last status it reported in the run.

Written directly as SVG (a layered layout: each subtree gets the width of its widest level, a
parent is centred over its children), so no graphviz install is needed. Condition guards that
the loader wraps around nodes are transparent: their node is drawn in their place. Hovering a
node shows its last message and where it is defined.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from xml.sax.saxutils import escape

from ..files import write_new

STYLE = {  # status -> (fill, stroke, label)
    "SUCCESS": ("#c8e6c9", "#2e7d32", "SUCCESS"),
    "FAILURE": ("#ffcdd2", "#c62828", "FAILURE"),
    "RUNNING": ("#fff9c4", "#f9a825", "RUNNING"),
    "HALTED": ("#ffe0b2", "#ef6c00", "halted"),
    "SKIPPED": ("#e1f5fe", "#0277bd", "SKIPPED"),
    "IDLE": ("#f5f5f5", "#9e9e9e", "not ticked"),
}
CHAR_W, LINE_H, PAD, GAP, LEVEL_H, MARGIN = 7.0, 15, 10, 14, 80, 20


@dataclass
class Box:
    id: int
    name: str
    type: str
    status: str
    message: str
    location: str | None
    children: list["Box"] = field(default_factory=list)
    x: float = 0.0
    y: float = 0.0

    @property
    def lines(self) -> list[str]:
        lines = [self.name]
        if self.type and self.type != self.name:
            lines.append(self.type)
        lines.append(STYLE[self.status][2])
        return lines

    @property
    def w(self) -> float:
        return max(len(line) for line in self.lines) * CHAR_W + 2 * PAD

    @property
    def h(self) -> float:
        return len(self.lines) * LINE_H + PAD


def display_status(status: str | None, message: str) -> str:
    if status is None:
        return "IDLE"
    if status == "INVALID":
        return "HALTED" if message == "halted" else "IDLE"
    return status if status in STYLE else "IDLE"


def build_boxes(nodes: list[dict[str, Any]], statuses: dict[int, tuple[str, str]]) -> Box | None:
    """The visible tree: transparent guards replaced by their node, statuses attached."""
    by_id = {n["id"]: n for n in nodes}

    def visible_parent(node: dict[str, Any]) -> int | None:
        parent = node["parent"]
        while parent is not None and by_id[parent]["transparent"]:
            parent = by_id[parent]["parent"]
        result: int | None = parent
        return result

    def status_of(node: dict[str, Any]) -> tuple[str | None, str]:
        own = statuses.get(node["id"])
        if own is not None:
            return own
        parent = node["parent"]  # a guard that skipped its node reported for it
        while parent is not None and by_id[parent]["transparent"]:
            if parent in statuses:
                return statuses[parent]
            parent = by_id[parent]["parent"]
        return None, ""

    boxes: dict[int, Box] = {}
    for node in nodes:
        if node["transparent"]:
            continue
        status, message = status_of(node)
        boxes[node["id"]] = Box(node["id"], node["name"], node.get("type") or "", display_status(status, message),
                                message, node.get("location"))
    root = None
    for node in sorted(nodes, key=lambda n: n["id"]):  # children come before parents in iterate() order
        if node["transparent"]:
            continue
        parent = visible_parent(node)
        if parent is None:
            root = boxes[node["id"]]
        else:
            boxes[parent].children.append(boxes[node["id"]])
    return root


def _width(box: Box, memo: dict[int, float]) -> float:
    kids = sum(_width(c, memo) for c in box.children) + GAP * max(0, len(box.children) - 1)
    memo[box.id] = max(box.w, kids)
    return memo[box.id]


def _place(box: Box, left: float, depth: int, memo: dict[int, float]) -> None:
    box.x = left + memo[box.id] / 2
    box.y = MARGIN + 40 + depth * LEVEL_H
    kids = sum(memo[c.id] for c in box.children) + GAP * max(0, len(box.children) - 1)
    cursor = left + (memo[box.id] - kids) / 2
    for child in box.children:
        _place(child, cursor, depth + 1, memo)
        cursor += memo[child.id] + GAP


def _all(box: Box) -> list[Box]:
    out = [box]
    for child in box.children:
        out.extend(_all(child))
    return out


def tree_svg(nodes: list[dict[str, Any]], statuses: dict[int, tuple[str, str]], title: str = "") -> str:
    """The SVG text of the tree (see the module doc)."""
    root = build_boxes(nodes, statuses)
    if root is None:
        return ('<svg xmlns="http://www.w3.org/2000/svg" width="300" height="40">'
                '<text x="10" y="25" font-family="sans-serif" font-size="13">no tree was recorded</text></svg>\n')
    memo: dict[int, float] = {}
    _width(root, memo)
    _place(root, MARGIN, 0, memo)
    boxes = _all(root)
    width = memo[root.id] + 2 * MARGIN
    height = max(b.y + b.h for b in boxes) + MARGIN
    width = max(width, 620)
    out = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{width:.0f}" height="{height:.0f}" '
           f'viewBox="0 0 {width:.0f} {height:.0f}" font-family="sans-serif" font-size="12">',
           '<rect width="100%" height="100%" fill="white"/>',
           f'<text x="{MARGIN}" y="{MARGIN + 4}" font-size="14" font-weight="bold">{escape(title)}</text>']
    lx = MARGIN
    for status in ("SUCCESS", "FAILURE", "RUNNING", "HALTED", "SKIPPED", "IDLE"):
        fill, stroke, label = STYLE[status]
        out.append(f'<rect x="{lx}" y="{MARGIN + 14}" width="12" height="12" fill="{fill}" stroke="{stroke}"/>'
                   f'<text x="{lx + 16}" y="{MARGIN + 24}" font-size="11">{label}</text>')
        lx += 16 + len(label) * 7 + 14
    for box in boxes:
        for child in box.children:
            out.append(f'<line x1="{box.x:.1f}" y1="{box.y + box.h:.1f}" x2="{child.x:.1f}" y2="{child.y:.1f}" '
                       f'stroke="#888" stroke-width="1"/>')
    for box in boxes:
        fill, stroke, _ = STYLE[box.status]
        tip = f"{box.name} [{box.type}] {STYLE[box.status][2]}"
        if box.message:
            tip += f": {box.message}"
        if box.location:
            tip += f" ({box.location})"
        out.append(f'<g class="node" data-status="{box.status}"><title>{escape(tip)}</title>')
        out.append(f'<rect x="{box.x - box.w / 2:.1f}" y="{box.y:.1f}" width="{box.w:.1f}" height="{box.h:.1f}" '
                   f'rx="6" fill="{fill}" stroke="{stroke}" stroke-width="1.5"/>')
        for k, line in enumerate(box.lines):
            weight = ' font-weight="bold"' if k == 0 else ' font-size="11" fill="#444"'
            out.append(f'<text x="{box.x:.1f}" y="{box.y + PAD / 2 + (k + 1) * LINE_H - 3:.1f}" '
                       f'text-anchor="middle"{weight}>{escape(line)}</text>')
        out.append("</g>")
    out.append("</svg>\n")
    return "\n".join(out)


def write_tree_svg(nodes: list[dict[str, Any]], statuses: dict[int, tuple[str, str]], path: Path, title: str = "") -> Path:
    return write_new(path, tree_svg(nodes, statuses, title))
