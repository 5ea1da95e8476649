"""Sphinx configuration of the pmht-opt documentation: the Markdown pages and the API reference.

Build (docs/README.md): ``python -m sphinx -W --keep-going -b html docs docs/_build/html``.
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from sphinx.application import Sphinx

# Document the checkout being built, whatever else the environment has installed.
ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import pmht_opt  # noqa: E402

project = "pmht-opt"
author = "the pmht-opt developers"
copyright = "the pmht-opt developers"
release = pmht_opt.__version__
version = release

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
    "numpydoc",
    "myst_parser",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
root_doc = "index"
templates_path = ["_templates"]
# README.md says how to build; it is not a page of the site.
exclude_patterns = ["_build", "README.md"]

# -- API reference ---------------------------------------------------------------------------------
# The pages in api/ list every public name (tests/test_docs.py holds them to each ``__all__``); the
# stubs autosummary writes from those lists go to api/generated/, rewritten on every build and
# ignored by git.
autosummary_generate = True
autosummary_generate_overwrite = True
# Written afresh each time, so that a stub of a name no longer listed cannot linger.
shutil.rmtree(Path(__file__).parent / "api" / "generated", ignore_errors=True)
autosummary_imported_members = False
autodoc_default_options = {"members": True, "show-inheritance": True}
autodoc_member_order = "bysource"
# Signatures keep their annotations; the numpydoc sections carry the prose.
autodoc_typehints = "signature"
autodoc_preserve_defaults = True

# autodoc documents each class's own members in place; numpydoc's member tables would repeat them
# and list inherited ones that have no entry to link to.
numpydoc_show_class_members = False
numpydoc_attributes_as_param_list = True

# -- Markdown (docs/*.md) --------------------------------------------------------------------------
myst_enable_extensions = ["dollarmath", "amsmath"]
# The pages' ```math blocks are display equations, as GitHub renders them.
myst_fence_as_directive = ["math"]
# The pages link to their sections by GitHub's anchors ("#4-constraints").
myst_heading_anchors = 3

# -- HTML ------------------------------------------------------------------------------------------
html_theme = "alabaster"
html_title = f"pmht-opt {release}"
html_static_path: list[str] = []


def _no_signature_for_data(
    app: Sphinx, what: str, name: str, obj: Any, options: Any, signature: str | None, return_annotation: str
) -> tuple[()] | None:
    """Keep data without a signature.

    numpydoc gives a callable value (a type alias such as ``tuple[float, ...]``) the signature of its
    class, which is wrong for data and which Sphinx 9.0 fails on, dropping the entry. An empty result
    stops the event there (it is not None) and changes nothing (it is empty).
    """
    if what in ("data", "attribute"):
        return ()
    return None


def setup(app: Sphinx) -> None:
    # Before numpydoc's handler (priority 500).
    app.connect("autodoc-process-signature", _no_signature_for_data, priority=400)
