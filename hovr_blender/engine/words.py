"""Numbers in words for messages: "1 element", "2 elements"; a reader's many like warnings as a few lines."""
from __future__ import annotations

import re


def plural(count: int, noun: str, nouns: str | None = None) -> str:
    """'1 element', '1,760 elements' ('1 vertex', '2 vertices' with nouns='vertices')."""
    return f"{count:,} {noun if count == 1 else (nouns or noun + 's')}"


_NUMBERED = re.compile(r"\b(face|element|edge|curve|vertex|composite|cell) (\d+)\b")


def summarise_warnings(warnings, limit: int = 5, examples: int = 4) -> list[str]:
    """Warnings that differ only in the number of a face, element, edge... (a reader's per-face
    notes) as one line each: the first in full, then how many more and a few of their numbers.
    At most `limit` lines; the order of first appearance is kept."""
    groups: dict[str, list[tuple[str, str]]] = {}
    for w in warnings:
        match = _NUMBERED.search(w)
        key = _NUMBERED.sub(lambda m: m.group(1) + " #", w, count=1) if match else w
        groups.setdefault(key, []).append((w, match.group(2) if match else ""))
    lines = []
    for members in groups.values():
        first, _ = members[0]
        if len(members) == 1:
            lines.append(first)
            continue
        noun = _NUMBERED.search(first).group(1)
        noun = "vertices" if noun == "vertex" else noun + "s"
        more = [number for _, number in members[1:]]
        shown = ", ".join(more[:examples]) + (", ..." if len(more) > examples else "")
        lines.append(f"{first} (and {len(more)} more {noun} like it: {shown})")
    if len(lines) > limit:
        lines = lines[:limit - 1] + [f"{len(lines) - limit + 1} more kinds of warning"]
    return lines
