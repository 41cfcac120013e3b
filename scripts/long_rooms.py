"""Rooms too long to read (issue 28): ``python scripts/long_rooms.py [ROOT ...]`` (default
``lidar_mitsuba plugins``) prints every function over :data:`MAX_FUNCTION_LINES` lines, class
over :data:`MAX_CLASS_LINES` and module over :data:`MAX_MODULE_LINES`, longest first, and
exits 1 when it finds one. ``tests/test_layout.py`` holds the package to these limits.

A room's length counts every line from its ``def``/``class`` to its last line, docstring and
comments included (what a reader has to hold at once).
"""
from __future__ import annotations

import ast
import pathlib
import sys

MAX_FUNCTION_LINES = 80
MAX_CLASS_LINES = 300
MAX_MODULE_LINES = 600
ROOT = pathlib.Path(__file__).resolve().parents[1]


def long_rooms(*roots: str | pathlib.Path) -> list[tuple[int, str, int, str, str]]:
    """Every room over its limit under ``roots`` (folders, relative to the repository or
    absolute): ``(lines, path relative to the repository, first line, kind, name)``, kind
    ``function``, ``class`` or ``module`` (name ``""``), longest first."""
    rows = []
    for root in roots:
        for p in sorted((ROOT / root).rglob("*.py")):
            rel = p.relative_to(ROOT).as_posix()
            src = p.read_text()
            n = len(src.splitlines())
            if n > MAX_MODULE_LINES:
                rows.append((n, rel, 1, "module", ""))
            for node in ast.walk(ast.parse(src)):
                if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                    kind, limit = "function", MAX_FUNCTION_LINES
                elif isinstance(node, ast.ClassDef):
                    kind, limit = "class", MAX_CLASS_LINES
                else:
                    continue
                length = node.end_lineno - node.lineno + 1
                if length > limit:
                    rows.append((length, rel, node.lineno, kind, node.name))
    return sorted(rows, key=lambda r: (-r[0], r[1], r[2]))


def main(argv: list[str]) -> int:
    rows = long_rooms(*(argv or ["lidar_mitsuba", "plugins"]))
    for length, path, line, kind, name in rows:
        print(f"{length:5d}  {path}:{line}  {kind} {name}".rstrip())
    return 1 if rows else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
