"""Command-line options generated from the API: one option per dataclass field or keyword
argument, with its type, default and help taken from the code and its docstring, so that the
CLI never repeats a default or a description.

Every generated option defaults to ``None`` (not given); :func:`given` collects the options a
user did give, and the dataclass or function then applies its own defaults. That also tells
the CLI which options were given explicitly (e.g. to refuse surface options with ``--scene``).
"""
from __future__ import annotations

import argparse
import dataclasses
import inspect
import re
import types
import typing


def option_name(name: str) -> str:
    """The CLI option of an API name: ``grid_m`` -> ``--grid-m`` (a few are renamed)."""
    return RENAMED.get(name, "--" + name.replace("_", "-"))


#: API names whose option is spelled differently
RENAMED = {"kind": "--surface", "scene": "--scene", "scene_file": "--scene", "params": "-D",
           "lat_deg": "--lat", "lon_deg": "--lon", "height_m": "--site-height-m"}


def doc_entries(obj) -> dict[str, str]:
    """``name -> description`` from the ``Attributes:`` or ``Args:`` section of ``obj``'s
    Google-style docstring (an entry may name several fields: ``a, b: ...``)."""
    doc = inspect.getdoc(obj) or ""
    out: dict[str, str] = {}
    current: list[str] = []
    section = False
    for line in doc.splitlines():
        if line.strip() in ("Attributes:", "Args:"):
            section, current = True, []
            continue
        if not section:
            continue
        if line and not line.startswith(" "):        # the next section
            section = False
            continue
        m = re.match(r"^ {4}(\w+(?:, \w+)*): ?(.*)$", line)
        if m:
            current = m.group(1).split(", ")
            for name in current:
                out[name] = m.group(2).strip()
        elif line.startswith(" " * 8) and current:
            for name in current:
                out[name] += " " + line.strip()
    return out


def _plain(text: str) -> str:
    """The first sentence of a docstring entry, without reST markup."""
    text = re.sub(r":\w+:`~?([^`]*)`", lambda m: m.group(1).split(".")[-1], text)
    text = text.replace("``", "")
    depth = 0
    for i, ch in enumerate(text):          # the first '.' or ';' outside parentheses
        depth += (ch in "([") - (ch in ")]")
        if (depth == 0 and ch in ".;" and (i + 1 == len(text) or text[i + 1] == " ")
                and not text[max(0, i - 3):i + 1].endswith(("e.g.", "i.e."))):
            return text[:i]
    return text.rstrip(".;")


def _base_type(hint):
    """``float | None`` -> float; ``tuple[float, float] | None`` -> that tuple type."""
    if isinstance(hint, types.UnionType) or typing.get_origin(hint) is typing.Union:
        args = [a for a in typing.get_args(hint) if a is not type(None)]
        return args[0] if len(args) == 1 else hint
    return hint


def _spec(owner) -> list[tuple[str, object, object, dict]]:
    """``(name, type hint, default, metadata)`` of a dataclass's fields or a function's
    keyword arguments."""
    hints = typing.get_type_hints(owner)
    if dataclasses.is_dataclass(owner):
        return [(f.name, hints.get(f.name), f.default, dict(f.metadata))
                for f in dataclasses.fields(owner) if f.init]
    return [(p.name, hints.get(p.name), p.default, {})
            for p in inspect.signature(owner).parameters.values()]


def add_options(group, owner, *, only=None, skip=(), types_: dict | None = None,
                metavars: dict | None = None) -> list[str]:
    """Add one option per field of dataclass ``owner`` (or keyword of function ``owner``) to
    the argparse ``group``; returns the API names added.

    Args:
        only / skip: names to include / leave out.
        types_: name -> argparse ``type`` callable replacing the one from the type hint.
        metavars: name -> metavar.
    """
    docs = doc_entries(owner)
    added = []
    for name, hint, default, meta in _spec(owner):
        if (only is not None and name not in only) or name in skip:
            continue
        base = _base_type(hint)
        kw: dict = {"default": None, "dest": name}
        show = default not in (None, dataclasses.MISSING, inspect.Parameter.empty)
        if base is bool:
            kw.update(action="store_const", const=True)
            show = False
        elif typing.get_origin(base) is tuple:
            kw.update(nargs=len(typing.get_args(base)), type=typing.get_args(base)[0])
        elif (types_ or {}).get(name):
            kw["type"] = types_[name]
        elif base in (int, float, str):
            kw["type"] = base
        if "choices" in meta:
            kw["choices"] = meta["choices"]
        if metavars and name in metavars:
            kw["metavar"] = metavars[name]
        elif "choices" not in meta and kw.get("action") is None:
            kw["metavar"] = _metavar(name, base)
        text = _plain(docs.get(name, name.replace("_", " ")))
        if "presets" in meta:
            text += " (or a preset: " + ", ".join(f"{k} = {v:g}" for k, v in
                                                  meta["presets"].items()) + ")"
        if "default_help" in meta:
            text += f" (default: {meta['default_help']})"
        elif show:
            text += f" (default {default:g})" if isinstance(default, float) else \
                f" (default {default})"
        kw["help"] = text.replace("%", "%%")
        group.add_argument(option_name(name), **kw)
        added.append(name)
    return added


_UNITS = ("m", "deg", "ns", "hz", "mhz", "nm", "s")


def _metavar(name: str, base) -> str:
    """The unit for a quantity whose name carries one (``--relief-m M``), else X or N."""
    unit = name.rsplit("_", 1)[-1]
    if "_" in name and unit in _UNITS:
        return unit.upper()
    return "N" if base is int else "X" if base is float else name.upper()


def given(args: argparse.Namespace, names) -> dict:
    """The options among ``names`` that the user gave: ``{api name: value}``."""
    out = {}
    for n in names:
        v = getattr(args, n, None)
        if v is not None:
            out[n] = tuple(v) if isinstance(v, list) else v
    return out
