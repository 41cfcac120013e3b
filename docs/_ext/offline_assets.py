"""The site's JavaScript, shipped inside the built site so that it works without a network.

Many users read the documentation on clusters offline, or open ``index.html`` straight from
the disk (``file://``). So nothing is loaded from a CDN: MathJax (which typesets the
equations) and Mermaid (which draws the diagrams of ``docs/architecture.md``) are copied into
the site's ``_static/`` folder, each file with its licence, and the pages load them from there
with classic ``<script>`` tags (ES modules are refused from ``file://`` by Chromium).

Where the files come from: the npm registry's packages, pinned below and fetched once, by
``scripts/setup.sh --test`` (or ``python docs/_ext/offline_assets.py``), with the machine's
``npm pack`` (one tarball per package, no ``node_modules``; npm checks the registry's
integrity hash), into ``<sys.prefix>/share/lidar_mitsuba-docs/`` (the virtual environment,
like the ``docs`` extra's Python packages). Each file's SHA-256 is checked against the pin
when it is fetched and again at every build.

- MathJax 3.2.2, ``es5/tex-svg-full.js`` (2.3 MB, Apache-2.0): every TeX extension and the SVG
  output in one file, so it loads no other component and no web font.
- Mermaid 11.12.1, ``dist/mermaid.min.js`` (2.7 MB, MIT): the self-contained browser bundle
  (the version sphinxcontrib-mermaid 2.1 pins; 12.x's bundle is twice the size).

As a Sphinx extension: it adds that folder to ``html_static_path``, points ``mathjax_path`` at
the local MathJax (in ``conf.py``) and turns each ``mermaid`` code block into a
``<pre class="mermaid">`` that the local Mermaid draws when the page loads (the source text
stays readable where JavaScript is off); a page without a diagram loads no Mermaid.
"""
from __future__ import annotations

import hashlib
import html
import pathlib
import shutil
import subprocess
import sys
import tarfile
import tempfile
from dataclasses import dataclass

from docutils import nodes

#: where the fetched files live (the environment's share/ folder, outside the repository)
ASSET_DIR = pathlib.Path(sys.prefix) / "share" / "lidar_mitsuba-docs"


@dataclass(frozen=True)
class Asset:
    """One file of an npm package, shipped in the site at ``_static/<dest>``."""
    package: str        # npm name@version
    member: str         # path inside the package's tarball
    dest: str           # path under ASSET_DIR and under the site's _static/
    sha256: str         # of the file as the registry's tarball holds it


# SHA-256 values: of the files in the registry's tarballs, computed here when they were pinned
ASSETS = (
    Asset("mathjax@3.2.2", "package/es5/tex-svg-full.js", "mathjax/tex-svg-full.js",
          "a4354ff94fd868aea0cc6eaaa79a57fda0588646fc46ee3700a349ee0a11cbe6"),
    Asset("mathjax@3.2.2", "package/LICENSE", "mathjax/LICENSE",
          "cfc7749b96f63bd31c3c42b5c471bf756814053e847c10f3eb003417bc523d30"),
    Asset("mermaid@11.12.1", "package/dist/mermaid.min.js", "mermaid/mermaid.min.js",
          "198b19442f86f0b46a17e56d3abf744c3a28a3427e66fa8dada3b589a77babcc"),
    Asset("mermaid@11.12.1", "package/LICENSE", "mermaid/LICENSE",
          "ec9fb67dcb25eccc416ed56e1aab819222c805a2a4bfe4cb19e7556bf2ffde80"),
)
#: ``mathjax_path`` (relative to the site's _static/)
MATHJAX_JS = "mathjax/tex-svg-full.js"
MERMAID_JS = "mermaid/mermaid.min.js"
FETCH_HINT = ("run `bash scripts/setup.sh --test` (or `python docs/_ext/offline_assets.py` "
              "with the Python that builds the docs)")


def sha256(path: pathlib.Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def missing(asset_dir: pathlib.Path = ASSET_DIR) -> list[str]:
    """The assets absent from ``asset_dir`` or not the pinned files (empty: all there)."""
    return [a.dest for a in ASSETS
            if not (asset_dir / a.dest).is_file() or sha256(asset_dir / a.dest) != a.sha256]


def fetch(asset_dir: pathlib.Path = ASSET_DIR) -> list[str]:
    """Fetch the assets that :func:`missing` names with ``npm pack`` (one tarball per
    package, into a temporary folder) and extract their files; returns what was written.

    Raises:
        RuntimeError: npm is not on the PATH, or a file is not the pinned one.
    """
    todo = [a for a in ASSETS if a.dest in missing(asset_dir)]
    npm = shutil.which("npm")
    if todo and npm is None:
        raise RuntimeError("the docs' MathJax and Mermaid come from the npm registry: "
                           "install Node.js and npm (Debian: apt-get install npm)")
    with tempfile.TemporaryDirectory() as tmp:
        for package in sorted({a.package for a in todo}):
            out = subprocess.run([npm, "pack", package, "--silent", "--pack-destination", tmp],
                                 capture_output=True, text=True, check=True)
            tarball = pathlib.Path(tmp) / out.stdout.strip().splitlines()[-1]
            with tarfile.open(tarball) as tar:
                for a in (a for a in todo if a.package == package):
                    data = tar.extractfile(a.member).read()
                    if hashlib.sha256(data).hexdigest() != a.sha256:
                        raise RuntimeError(f"{package} {a.member}: not the pinned file "
                                           f"(SHA-256 {hashlib.sha256(data).hexdigest()})")
                    target = asset_dir / a.dest
                    target.parent.mkdir(parents=True, exist_ok=True)
                    partial = target.with_suffix(target.suffix + ".part")
                    partial.write_bytes(data)
                    partial.replace(target)
    return [a.dest for a in todo]


# --- the Sphinx extension -------------------------------------------------------------------

class mermaid_diagram(nodes.General, nodes.Element):
    """A Mermaid diagram's source, drawn in the browser by the site's own mermaid.min.js."""


def _html_visit_mermaid(self, node):
    self.body.append(f'<pre class="mermaid">\n{html.escape(node["code"])}\n</pre>\n')
    raise nodes.SkipNode


def _mermaid_blocks(app, doctree, docname):
    """Every ``mermaid`` code block of an HTML page becomes a diagram (other builders keep the
    block, shown as source)."""
    if app.builder.format != "html":
        return
    for block in list(doctree.findall(nodes.literal_block)):
        if block.get("language") == "mermaid":
            block.replace_self(mermaid_diagram(code=block.astext()))


#: runs after the deferred mermaid.min.js; the pydata theme's dark mode gets Mermaid's dark
#: theme; a diagram keeps its natural size (its text readable) and scrolls sideways in its
#: block where it is wider than the page (architecture.md's are 1800 and 4200 px wide)
MERMAID_INIT = """document.addEventListener("DOMContentLoaded", function () {
  var dark = document.documentElement.dataset.theme === "dark";
  mermaid.initialize({startOnLoad: false, securityLevel: "strict",
                      theme: dark ? "dark" : "default", flowchart: {useMaxWidth: false}});
  mermaid.run({querySelector: "pre.mermaid"});
});"""


def _page_scripts(app, pagename, templatename, context, doctree):
    if doctree is not None and any(True for _ in doctree.findall(mermaid_diagram)):
        app.builder.add_js_file(MERMAID_JS, defer="defer")
        app.builder.add_js_file("", body=MERMAID_INIT)


def _check_assets(app):
    if app.builder.format == "html" and missing():
        from sphinx.errors import ConfigError
        raise ConfigError(f"the site's offline MathJax/Mermaid are missing or not the pinned "
                          f"files in {ASSET_DIR} ({', '.join(missing())}): {FETCH_HINT}")


def setup(app):
    from pygments.lexers.special import TextLexer
    app.add_lexer("mermaid", TextLexer)     # a diagram's source, where a builder shows it
    app.add_node(mermaid_diagram, html=(_html_visit_mermaid, None))
    app.connect("builder-inited", _check_assets)
    app.connect("doctree-resolved", _mermaid_blocks)
    app.connect("html-page-context", _page_scripts)
    return {"parallel_read_safe": True, "parallel_write_safe": True, "version": "1"}


if __name__ == "__main__":
    written = fetch()
    print(f"docs assets in {ASSET_DIR}: " + (f"fetched {', '.join(written)}" if written
                                               else "all present"))
