"""Sphinx configuration of haa_sym's documentation site (`make docs`; CI builds it with -W).

The pages are the Markdown files of docs/ (myst-parser); the API page is autodoc over the
numpydoc docstrings (read by sphinx.ext.napoleon), imported from ../src.
"""
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "src"))

import haa_sym  # noqa: E402 - after the path, so the API page documents this tree

project = "haa_sym"
author = "the haa_sym authors"
release = version = haa_sym.__version__
copyright = "the haa_sym authors, MIT licence"

extensions = ["myst_parser", "sphinx.ext.autodoc", "sphinx.ext.napoleon", "sphinx.ext.mathjax",
              "sphinx.ext.viewcode"]
source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
root_doc = "index"
exclude_patterns = ["_build", "Thumbs.db", ".DS_Store"]

# Markdown: heading anchors for the pages' links to sections (`model.md#fast-sampling-...`)
myst_heading_anchors = 3
myst_enable_extensions = ["colon_fence", "dollarmath"]

# numpydoc docstrings (Parameters / Returns / Examples sections), read by napoleon
napoleon_google_docstring = False
napoleon_numpy_docstring = True
napoleon_use_rtype = False
autodoc_member_order = "bysource"
autodoc_typehints = "description"
autodoc_default_options = {"members": True, "undoc-members": False, "show-inheritance": False}

html_theme = "alabaster"
html_title = f"haa_sym {release}"
html_static_path: list[str] = []
