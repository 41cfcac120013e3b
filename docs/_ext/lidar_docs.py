"""Sphinx helpers of the lidar_mitsuba documentation (offline, no network).

- ``.. lidar-exports::``: the front door, a table of ``lidar_mitsuba._EXPORTS`` grouped as the
  source groups it, each name linked to the stage module that documents it.
- ``.. lidar-plugin:: NAME`` (a whole line of an ``.rst`` page, replaced when the page is
  read): the docstring of the plugin class in ``plugins/NAME.py``, read with :mod:`ast` (so the
  plugin is not imported), in Mitsuba's own documentation style.
- ``.. lidar-cli::`` (likewise): every subcommand's ``--help``, from the CLI's own parser.
- What Mitsuba's plugin docstrings use: ``.. pluginparameters::`` (a parameter table),
  ``.. tabs::`` / ``.. code-tab:: xml|python`` (an XML and a dict example), the ``:monosp:``
  role and the ``|float|``, ``|int|``, ... type names (:data:`RST_PROLOG`).
"""
from __future__ import annotations

import ast
import importlib
import inspect
import os
import pathlib
import re

from docutils import nodes
from docutils.parsers.rst import directives
from docutils.parsers.rst.directives.tables import ListTable
from docutils.statemachine import StringList
from sphinx.directives.code import CodeBlock
from sphinx.util import logging
from sphinx.util.docutils import SphinxDirective

logger = logging.getLogger(__name__)

ROOT = pathlib.Path(__file__).resolve().parents[2]
PLUGINS = ROOT / "plugins"

#: the type names of Mitsuba's plugin parameter tables
TYPE_NAMES = ("float", "int", "bool", "string", "spectrum", "texture", "rgb", "point",
              "vector", "transform", "medium", "phase", "bsdf", "shape")
RST_PROLOG = "\n".join(f".. |{t}| replace:: *{t}*" for t in TYPE_NAMES) + "\n"


# --- the plugins ----------------------------------------------------------------------------

def plugin_names() -> list[str]:
    """``lidar_mitsuba_plugins.PLUGIN_FILES``, read from its source (no Mitsuba import)."""
    tree = ast.parse((PLUGINS / "__init__.py").read_text())
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", "") == "PLUGIN_FILES"
                                                for t in node.targets):
            return list(ast.literal_eval(node.value))
    raise RuntimeError("plugins/__init__.py: no PLUGIN_FILES")


def plugin_docstring(name: str) -> str:
    """The docstring of the plugin class of ``plugins/NAME.py``: the class whose docstring has
    Mitsuba's title line ``Title (:monosp:`NAME`)``."""
    tree = ast.parse((PLUGINS / f"{name}.py").read_text())
    for node in tree.body:
        doc = ast.get_docstring(node, clean=True) if isinstance(node, ast.ClassDef) else None
        if doc and f":monosp:`{name}`" in doc.splitlines()[0]:
            return doc
    raise RuntimeError(f"plugins/{name}.py: no class documented as :monosp:`{name}`")


def plugin_parameters(name: str) -> list[str]:
    """The parameter names of a plugin's ``pluginparameters`` table (``(others)`` left out)."""
    names = []
    for m in re.finditer(r"^ \* - (.+)$", plugin_docstring(name), re.M):
        names += [n.strip() for n in m.group(1).split(",") if not n.strip().startswith("(")]
    return names


class PluginParameters(ListTable):
    """``.. pluginparameters::``: Mitsuba's three-column table (parameter, type, description)."""
    option_spec = {}

    def run(self):
        self.options = {"header-rows": 1, "widths": "20 20 60", "class": ["pluginparameters"]}
        src = self.content.source(0) if self.content else ""
        rows = StringList(["* - Parameter", "  - Type", "  - Description"], items=[(src, 0)] * 3)
        for i, line in enumerate(self.content):
            rows.append(line, *self.content.info(i))
            if line.startswith("* - ") and self._cells(i) == 2:    # "(others)": no type
                rows.append("  -", *self.content.info(i))
        self.content = rows
        return super().run()

    def _cells(self, i: int) -> int:
        """The cells of the row that begins at content line ``i``."""
        n = 1
        for line in self.content[i + 1:]:
            if line.startswith("* - "):
                break
            n += line.startswith("  - ")
        return n


class Tabs(SphinxDirective):
    """``.. tabs::``: a plain container for the ``code-tab`` blocks inside it."""
    has_content = True

    def run(self):
        box = nodes.container(classes=["plugin-examples"])
        self.state.nested_parse(self.content, self.content_offset, box)
        return [box]


class CodeTab(CodeBlock):
    """``.. code-tab:: LANGUAGE``: a code block captioned with its language."""
    CAPTIONS = {"xml": "XML", "python": "Python (a dict for mi.load_dict)"}

    def run(self):
        self.options.setdefault("caption", self.CAPTIONS.get(self.arguments[0],
                                                             self.arguments[0]))
        return super().run()


def monosp_role(name, rawtext, text, lineno, inliner, options=None, content=None):
    return [nodes.literal(rawtext, text)], []


# --- the command line ----------------------------------------------------------------------

def cli_help_rst() -> str:
    """Every subcommand's ``--help`` (the CLI's own parser, 96 columns), as sections."""
    import argparse
    from lidar_mitsuba.cli import build_parser
    old = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = "96"
    try:
        parser = build_parser()
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        parts = [("lidar-mitsuba", parser)] + [(f"lidar-mitsuba {n}", p)
                                               for n, p in sub.choices.items()]
        out = []
        for title, p in parts:
            text = p.format_help().rstrip()
            out += [f"``{title}``", "-" * (len(title) + 4), "", ".. code-block:: text", ""]
            out += ["   " + line if line else "" for line in text.splitlines()] + [""]
        return "\n".join(out)
    finally:
        if old is None:
            os.environ.pop("COLUMNS", None)
        else:
            os.environ["COLUMNS"] = old


# --- the front door ------------------------------------------------------------------------

def export_groups() -> list[tuple[str, list[str]]]:
    """``_EXPORTS``' names in the groups its source comments give (``# a run``, ...)."""
    import lidar_mitsuba
    src = inspect.getsource(lidar_mitsuba).split("_EXPORTS = {", 1)[1].split("\n}", 1)[0]
    groups: list[tuple[str, list[str]]] = []
    for line in src.splitlines():
        line = line.strip()
        if line.startswith("#"):
            groups.append((line.lstrip("# ").capitalize(), []))
        elif m := re.match(r'"(\w+)":', line):
            if not groups:
                groups.append(("", []))
            groups[-1][1].append(m.group(1))
    listed = {n for _, names in groups for n in names}
    missing = sorted(set(lidar_mitsuba._EXPORTS) - listed)
    if missing:
        groups.append(("Other", missing))
    return groups


def _summary(obj) -> str:
    """The first sentence of an object's docstring (a period outside inline literals), or
    the value of a constant."""
    if not (inspect.isclass(obj) or inspect.isroutine(obj)):
        return f"``{obj!r}``"
    para = (inspect.getdoc(obj) or "").split("\n\n", 1)[0].replace("\n", " ").strip()
    # roles as plain literals: a docstring's short names resolve in its module, not here
    para = re.sub(r":(?:py:)?\w+:`~?([^`]+)`", r"``\1``", para)
    for m in re.finditer(r"\.(\s|$)", para):
        if para[:m.start()].count("``") % 2 == 0 and para[:m.start()].count("`") % 2 == 0:
            return para[:m.start() + 1]
    return para


class Exports(SphinxDirective):
    """``.. lidar-exports::``: one table per group of ``lidar_mitsuba._EXPORTS``."""

    def run(self):
        import lidar_mitsuba
        page = self.state.document.current_source        # the links are this page's own
        lines = StringList()
        for group, names in export_groups():
            for text in (f".. rubric:: {group}", "", ".. list-table::", "   :widths: 22 33 45",
                         "   :header-rows: 1", "", "   * - ``lm.`` name", "     - defined as",
                         "     - summary"):
                lines.append(text, page, self.lineno)
            for name in names:
                module, attr = lidar_mitsuba._EXPORTS[name]
                obj = getattr(importlib.import_module(module), attr)
                documented = inspect.isclass(obj) or inspect.isroutine(obj)
                target = f":py:obj:`{module}.{attr}`" if documented else f"``{module}.{attr}``"
                lines.append(f"   * - ``lm.{name}``", page, self.lineno)
                lines.append(f"     - {target}", page, self.lineno)
                lines.append(f"     - {_summary(obj) or ' '}", f"docstring of {module}.{attr}", 0)
            lines.append("", page, self.lineno)
        box = nodes.container()
        self.state.nested_parse(lines, 0, box)
        return box.children


# --- docstrings -----------------------------------------------------------------------------

SECTION_NOTE = re.compile(r"^(\s*)(Args|Arguments|Attributes|Returns|Raises|Yields)"
                          r"\s+\((.+)\):\s*$")


def _section_notes(app, what, name, obj, options, lines):
    """``Attributes (per-shot arrays ...):`` becomes the note as a sentence, then
    ``Attributes:``, the header napoleon reads (runs before napoleon)."""
    for i, line in enumerate(list(lines)):
        m = SECTION_NOTE.match(line)
        if m:
            indent, section, note = m.groups()
            j = lines.index(line)
            lines[j:j + 1] = [f"{indent}{note[0].upper()}{note[1:]}.", "", f"{indent}{section}:"]


def _missing_reference(app, env, node, contnode):
    """A Python cross-reference that nothing resolved, written on a page of ``docs/`` (not in a
    docstring, which names objects loosely): a warning, so ``-W`` fails the build on a dead
    link into the API."""
    doc, source = node.get("refdoc", ""), node.source or ""
    written = source.endswith((".md", ".rst")) and pathlib.Path(source).is_file()
    if node.get("refdomain") == "py" and written and not doc.startswith("reference/generated/"):
        logger.warning(f"unresolved Python reference {node.get('reftarget')!r}", location=node)


# --- whole-line placeholders, replaced when a page is read --------------------------------

PLACEHOLDER = re.compile(r"^\.\. (lidar-plugin|lidar-cli)::[ \t]*(\w*)[ \t]*$", re.M)


def _expand(app, docname, source):
    def replace(m):
        kind, arg = m.group(1), m.group(2)
        if kind == "lidar-cli":
            return cli_help_rst()
        app.env.note_dependency(str(PLUGINS / f"{arg}.py"))
        return plugin_docstring(arg)
    source[0] = PLACEHOLDER.sub(replace, source[0])


def setup(app):
    app.connect("source-read", _expand)
    app.connect("autodoc-process-docstring", _section_notes, priority=100)
    app.connect("missing-reference", _missing_reference, priority=999)
    app.add_directive("pluginparameters", PluginParameters)
    app.add_directive("tabs", Tabs)
    app.add_directive("code-tab", CodeTab)
    app.add_directive("lidar-exports", Exports)
    app.add_role("monosp", monosp_role)
    return {"parallel_read_safe": True, "parallel_write_safe": True, "version": "1"}
