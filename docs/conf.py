"""Sphinx configuration of the lidar_mitsuba documentation.

Build (offline, warnings as errors), from the repository root::

    .venv/bin/python -m sphinx -W --keep-going -b html docs docs/_build/html

Nothing is fetched and nothing is rendered: the notebooks are shown with their stored outputs
(``nb_execution_mode = "off"``), the gallery's images are committed PNGs
(``docs/gallery/make_gallery.py`` makes them) and there is no intersphinx. The built site needs
no network either: MathJax (the equations) and Mermaid (the diagrams) are copied into its
``_static/`` from the copies ``scripts/setup.sh --test`` fetched once (``_ext/offline_assets.py``).
"""
from __future__ import annotations

import os
import pathlib
import sys

HERE = pathlib.Path(__file__).resolve().parent
ROOT = HERE.parent
sys.path.insert(0, str(HERE / "_ext"))
sys.path.insert(0, str(ROOT))          # the checkout's own code, whatever is installed
os.environ.setdefault("MPLBACKEND", "Agg")

import lidar_mitsuba                    # noqa: E402  (cheap: loads no renderer)
from lidar_docs import RST_PROLOG       # noqa: E402
from offline_assets import ASSET_DIR, MATHJAX_JS  # noqa: E402

project = "lidar_mitsuba"
author = "the lidar_mitsuba authors"
copyright = "the lidar_mitsuba authors, BSD-3-Clause"
version = release = lidar_mitsuba.__version__

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.napoleon",
    "sphinx.ext.mathjax",
    "myst_nb",
    "lidar_docs",
    "offline_assets",
]

exclude_patterns = ["_build", "Thumbs.db", ".DS_Store", "**.ipynb_checkpoints", "_templates",
                    "gallery/make_gallery.py"]
templates_path = ["_templates"]
root_doc = "index"
rst_prolog = RST_PROLOG

# MyST Markdown (the guide) and notebooks: stored outputs, never executed here
myst_enable_extensions = ["dollarmath", "amsmath", "colon_fence", "deflist"]
myst_heading_anchors = 3
nb_execution_mode = "off"
nb_merge_streams = True

# API reference: one page per module (docs/_templates/autosummary/module.rst), members from
# the docstrings: Google style ("Args:", "Returns:", "Attributes:"), NumPy style in a few
autosummary_generate = True
autosummary_imported_members = False
autodoc_default_options = {"members": True, "show-inheritance": True,
                           "ignore-module-all": True}
autodoc_member_order = "bysource"
autodoc_typehints = "description"
autodoc_typehints_description_target = "documented"
autodoc_preserve_defaults = True
# no signature takes its types from "# type:" comments (they are annotations): reading every
# function's source again for them was ~5 % of the build (tests/test_docs.py builds the site)
autodoc_use_type_comments = False
napoleon_google_docstring = True
napoleon_numpy_docstring = True
# "Attributes:" as a list under that heading, like the parameters: several names may share
# one description ("surf, surf_cfg: the surface and its config"), as the docstrings write them
napoleon_custom_sections = [("Attributes", "params_style")]

html_theme = "pydata_sphinx_theme"
html_title = "lidar_mitsuba"
# the site's own MathJax and Mermaid (no CDN): copied into _static/, MathJax loaded from there
html_static_path = [str(ASSET_DIR)]
mathjax_path = MATHJAX_JS
html_theme_options = {
    "navigation_with_keys": False,
    "show_toc_level": 2,
    "navbar_align": "left",
    "footer_start": ["copyright"],
    "footer_end": ["sphinx-version"],
}
html_sidebars = {"index": []}
html_show_sourcelink = False
