"""Sphinx configuration of the pmht-opt documentation: the Markdown pages and the API reference.

Build (docs/README.md): ``python -m sphinx -W --keep-going -b html docs docs/_build/html``.
"""

from __future__ import annotations

import pkgutil
import shutil
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from docutils import nodes
    from sphinx.application import Sphinx
    from sphinx.environment import BuildEnvironment

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
autodoc_default_options = {"members": True, "show-inheritance": True}
autodoc_member_order = "bysource"
# Defaults as written (``DEFAULT_SIDES``), not as evaluated.
autodoc_preserve_defaults = True

# autodoc documents each class's own members in place; numpydoc's member tables would repeat them
# and list inherited ones that have no entry to link to.
numpydoc_show_class_members = False

# -- Markdown (docs/*.md) --------------------------------------------------------------------------
myst_enable_extensions = ["dollarmath", "amsmath"]
# The pages' ```math blocks are display equations, as GitHub renders them.
myst_fence_as_directive = ["math"]
# The pages link to their sections by GitHub's anchors ("#4-constraints").
myst_heading_anchors = 3

# -- HTML ------------------------------------------------------------------------------------------
html_theme = "alabaster"
html_title = f"pmht-opt {release}"


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


def _resolve(name: str) -> Any:
    try:
        return pkgutil.resolve_name(name)
    except Exception:  # not an importable name: a third-party type, a parameter, a typo
        return None


class _Documented:
    """The documented name of each documented class, exception and function: by the object's id, and
    by its last part where that is unique."""

    def __init__(self, env: BuildEnvironment) -> None:
        self.by_id: dict[int, str] = {}
        tails: dict[str, list[str]] = {}
        for name, entry in sorted(env.get_domain("py").objects.items()):
            obj = _resolve(name) if entry.objtype in ("class", "exception", "function") else None
            if obj is not None and id(obj) not in self.by_id:
                self.by_id[id(obj)] = name
                tails.setdefault(name.rpartition(".")[2], []).append(name)
        self.by_tail = {tail: names[0] for tail, names in tails.items() if len(names) == 1}

    def home(self, target: str, module: str | None) -> str | None:
        candidates = [target, f"{module}.{target}"] if module else [target]
        obj = next((o for o in map(_resolve, candidates) if o is not None), None)
        if obj is not None:
            return self.by_id.get(id(obj))
        return self.by_tail.get(target)


#: This build's index of documented objects, made once every source is read (ids hold in one process
#: only, so it is not kept with the pickled environment).
_documented: list[_Documented] = []


def _index_documented(app: Sphinx, env: BuildEnvironment) -> None:
    _documented[:] = [_Documented(env)]


def _link_other_paths(
    app: Sphinx, env: BuildEnvironment, node: nodes.Element, contnode: nodes.TextElement
) -> nodes.Element | None:
    """Link a name given by another of its import paths to where it is documented.

    Each object is documented once, under its subpackage (``pmht_opt.scenario.Scenario``); docstrings
    also name it as re-exported (``pmht_opt.Scenario``), as imported into the module they are in, or
    by its bare name from a module that does not import it.
    """
    if node.get("refdomain") != "py" or not _documented:
        return None
    target = node["reftarget"]
    home = _documented[0].home(target, node.get("py:module"))
    if home is None or home == target:
        return None
    py = env.get_domain("py")
    return py.resolve_xref(env, node["refdoc"], app.builder, node["reftype"], home, node, contnode)


def setup(app: Sphinx) -> None:
    # Before numpydoc's handler (priority 500).
    app.connect("autodoc-process-signature", _no_signature_for_data, priority=400)
    app.connect("env-updated", _index_documented)
    app.connect("missing-reference", _link_other_paths)
