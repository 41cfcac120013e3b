"""The ``lidar-mitsuba`` command lines shown in the documentation, for the gallery script
(``docs/gallery/make_gallery.py``) and the tests (``tests/test_docs.py``).

A command is a line of a fenced ``bash``/``sh``/``console``/``shell`` code block of a Markdown
page that runs ``lidar-mitsuba`` (``.venv/bin/lidar-mitsuba`` too): backslash continuations
joined, ``# comments`` dropped, ``&&`` chains split. Synopses (``text`` blocks) are not
commands.
"""
from __future__ import annotations

import dataclasses
import pathlib
import re
import shlex

SHELL_LANGUAGES = {"bash", "sh", "shell", "console"}
FENCE = re.compile(r"^(?P<indent> *)(?P<fence>`{3,}|~{3,})\s*(?P<lang>[\w+-]*)")
PROGRAM = "lidar-mitsuba"
#: options whose value is a file or folder the command writes
OUTPUT_OPTIONS = ("--out", "--atl06", "--plot")


@dataclasses.dataclass(frozen=True)
class Command:
    """One documented command: where it is and its arguments after ``lidar-mitsuba``."""
    path: pathlib.Path
    line: int
    argv: tuple[str, ...]

    @property
    def subcommand(self) -> str:
        return self.argv[0] if self.argv else ""

    @property
    def options(self) -> frozenset[str]:
        """The options it gives (``-D`` included), without their values."""
        return frozenset(a.split("=", 1)[0] for a in self.argv[1:]
                         if a.startswith("-") and not _is_number(a))

    def where(self) -> str:
        return f"{self.path}:{self.line}"

    def __str__(self) -> str:
        return " ".join([PROGRAM, *self.argv])


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True


def code_blocks(path: pathlib.Path):
    """``(language, first line number, lines)`` of every fenced code block of a Markdown page."""
    lines = pathlib.Path(path).read_text().splitlines()
    i = 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if not m:
            i += 1
            continue
        fence, indent, start = m.group("fence"), len(m.group("indent")), i + 1
        body = []
        i += 1
        while i < len(lines) and not lines[i].strip().startswith(fence):
            body.append(lines[i][indent:])
            i += 1
        yield m.group("lang").lower(), start + 1, body
        i += 1


def commands(path: pathlib.Path) -> list[Command]:
    """Every ``lidar-mitsuba`` command of the page's shell code blocks."""
    out = []
    for lang, first, body in code_blocks(path):
        if lang not in SHELL_LANGUAGES:
            continue
        joined, start = "", None
        for k, line in enumerate(body):
            start = first + k if start is None else start
            line = line[2:] if lang == "console" and line.startswith("$ ") else line
            if line.rstrip().endswith("\\"):
                joined += line.rstrip()[:-1] + " "
                continue
            out += _split(path, start, joined + line)
            joined, start = "", None
    return out


def _split(path, line, text) -> list[Command]:
    words = shlex.split(text, comments=True)
    found, part = [], []
    for w in words + ["&&"]:
        if w not in ("&&", ";", "||"):
            part.append(w)
            continue
        if part and pathlib.PurePath(part[0]).name == PROGRAM:
            found.append(Command(pathlib.Path(path), line, tuple(part[1:])))
        part = []
    return found


def documented_commands(root: pathlib.Path) -> list[Command]:
    """The commands of ``README.md`` and of every Markdown page under ``docs/``."""
    pages = [root / "README.md"] + sorted((root / "docs").rglob("*.md"))
    return [c for p in pages if "_build" not in p.parts for c in commands(p)]


def redirect_outputs(argv, out_dir: pathlib.Path, *, keep: dict | None = None) -> list[str]:
    """``argv`` with every written file (``--out``, ``--atl06``, ``--plot``) moved into
    ``out_dir``, and inputs that an earlier command wrote there (``--dem demo_dem.tif``,
    ``stats demo.h5``) read from it; ``keep`` maps file names to paths to use instead."""
    keep = keep or {}
    out = []
    args = list(argv)
    for i, a in enumerate(args):
        prev = args[i - 1] if i else ""
        if prev in OUTPUT_OPTIONS:
            name = pathlib.Path(a).name
            out.append(str(keep.get(name, out_dir / name)))
        elif not a.startswith("-") and (out_dir / pathlib.Path(a).name).exists():
            out.append(str(out_dir / pathlib.Path(a).name))     # written by an earlier command
        else:
            out.append(a)
    return out
