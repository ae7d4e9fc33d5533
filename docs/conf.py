"""Sphinx configuration of the SCET documentation (``make docs``: warnings are errors).

Markdown pages through MyST, the API reference from the numpydoc docstrings, the CLI reference
from ``scet``'s own parser (sphinx-argparse, so it cannot drift from the code) and a small
gallery of executed examples (sphinx-gallery, ``docs/examples``).
"""

from __future__ import annotations

import os
import sys
from importlib import metadata
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # the checkout's packages, whether installed or not

project = "SCET"
author = "the SCET authors"
copyright = "2026, the SCET authors"
try:
    release = metadata.version("scet")
except metadata.PackageNotFoundError:
    release = "0.1.0"
version = release

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
    "numpydoc",
    "sphinxarg.ext",
    "sphinx_gallery.gen_gallery",
]

source_suffix = {".md": "markdown", ".rst": "restructuredtext"}
exclude_patterns = ["_build", "examples/README.rst", "auto_examples/*.ipynb",
                    "auto_examples/*.py", "auto_examples/*.zip", "auto_examples/*.md5",
                    "auto_examples/*.json"]
myst_enable_extensions = ["dollarmath", "colon_fence", "deflist"]
myst_heading_anchors = 3
# The reports are included as written for GitHub: their first heading is the page title and
# their sections may skip a level.
suppress_warnings = ["myst.header"]

# API reference: numpydoc renders the docstrings; members are listed by autosummary tables
# on the API pages, not by numpydoc (which would list every attribute twice).
autosummary_generate = False
autodoc_member_order = "bysource"
autodoc_typehints = "none"
numpydoc_show_class_members = False
numpydoc_xref_param_type = False
numpydoc_validation_checks: set[str] = set()

# The gallery: executed on every build (a few small renders; under a minute on 2 cores).
# SCET_DOCS_GALLERY=0 skips running them (the pages then show the code without output).
sphinx_gallery_conf = {
    "examples_dirs": "examples",
    "gallery_dirs": "auto_examples",
    "filename_pattern": r"/plot_",
    "plot_gallery": os.environ.get("SCET_DOCS_GALLERY", "1") != "0",
    "download_all_examples": False,
    "remove_config_comments": True,
    "within_subsection_order": "FileNameSortKey",
    "show_memory": False,
    "abort_on_example_error": True,
}

html_theme = "pydata_sphinx_theme"
html_title = "SCET"
html_static_path: list[str] = []
html_theme_options = {
    "navigation_depth": 2,
    "show_toc_level": 2,
    "secondary_sidebar_items": ["page-toc"],
    "footer_start": ["copyright"],
    "footer_end": [],
}
html_show_sourcelink = False
