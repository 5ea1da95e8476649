"""The API reference lists every public name.

The pages in docs/api/ name what Sphinx documents: each section sets its namespace with
``.. currentmodule::`` and lists names under ``.. autosummary::``. These tests read those lists as
text (no Sphinx needed) and hold them to the code: every name in a documented namespace's
``__all__`` has an entry, and every entry is such a name. A module without ``__all__`` exports, by
the usual rule, every name it defines at the top level without a leading underscore.

An object reachable from several namespaces is documented once, under the deepest of them; the
others list it by that path (``~scenario.Scenario`` under ``pmht_opt``), so that every namespace's
list is complete and each entry links to the one page.
"""

from __future__ import annotations

import ast
import importlib
import pkgutil
import re
from pathlib import Path
from types import ModuleType

import pytest

import pmht_opt

API = Path(__file__).resolve().parent.parent / "docs" / "api"

#: The namespaces the reference documents: the package, its public subpackages and modules, and the
#: generic QP layer.
DOCUMENTED = (
    "pmht_opt",
    "pmht_opt.constraints",
    "pmht_opt.settings",
    "pmht_opt.scenario",
    "pmht_opt.result",
    "pmht_opt.stopping",
    "pmht_opt.exceptions",
    "pmht_opt.planners",
    "pmht_opt.ordering",
    "pmht_opt.ordering.ga",
    "pmht_opt.tours",
    "pmht_opt.geometry",
    "pmht_opt.io",
    "pmht_opt.io.qgc",
    "pmht_opt.plotting",
    "solvers",
)

#: pmht_opt's other packages and modules, and why they have no page of their own.
INTERNAL = {
    "__main__": "`python -m pmht_opt`, the command line",
    "cli": "the command line, documented by `pmht-opt --help`",
    "data": "package data",
    "anneal": "Anneal is re-exported by pmht_opt",
    "em": "EMRun, EMCallbacks and IterationRecord are re-exported by pmht_opt",
    "estep": "the E-step; EStepSummary is re-exported by pmht_opt",
    "mstep": "the M-step's backends; solve_mstep and available_backends are re-exported by pmht_opt",
    "model": "MotionModel is re-exported by pmht_opt",
    "schedule": "Schedule is re-exported by pmht_opt",
    "parallel": "the E-step's threads",
    "toml_writer": "the TOML files' writer",
    "validation": "the checks of arguments behind every constructor",
    "verify": "the verification of every returned plan",
}

_CURRENT = re.compile(r"\.\. currentmodule:: (\S+)\s*$")
_AUTOSUMMARY = re.compile(r"\.\. autosummary::\s*$")
_ENTRY = re.compile(r" {3}(~?[\w.]+)\s*$")


def listed() -> dict[str, list[str]]:
    """Each namespace's autosummary entries in docs/api/*.rst, as full dotted names."""
    sections: dict[str, list[str]] = {}
    for page in sorted(API.glob("*.rst")):
        module = None
        in_list = False
        for line in page.read_text(encoding="utf-8").splitlines():
            if match := _CURRENT.match(line):
                module = match.group(1)
                sections.setdefault(module, [])
                in_list = False
            elif _AUTOSUMMARY.match(line):
                assert module is not None, f"{page.name}: an autosummary before any currentmodule"
                in_list = True
            elif in_list and line.strip() and not line.startswith(" "):
                in_list = False
            elif in_list and (match := _ENTRY.match(line)):
                sections[module].append(f"{module}.{match.group(1).removeprefix('~')}")
    return sections


def defined_names(module: ModuleType) -> list[str]:
    """The names a module without ``__all__`` defines at the top level, without a leading underscore."""
    tree = ast.parse(Path(module.__file__ or "").read_text(encoding="utf-8"))
    names: list[str] = []
    for node in tree.body:
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.ClassDef):
            names.append(node.name)
        elif isinstance(node, ast.Assign):
            names += [target.id for target in node.targets if isinstance(target, ast.Name)]
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            names.append(node.target.id)
    return [name for name in names if not name.startswith("_")]


def public_names(namespace: str) -> list[str]:
    module = importlib.import_module(namespace)
    exported = getattr(module, "__all__", None)
    return list(exported) if exported is not None else defined_names(module)


@pytest.fixture(scope="module")
def sections() -> dict[str, list[str]]:
    return listed()


def test_the_pages_document_these_namespaces(sections: dict[str, list[str]]) -> None:
    assert sorted(sections) == sorted(DOCUMENTED)


@pytest.mark.parametrize("namespace", DOCUMENTED)
def test_every_public_name_has_an_entry(sections: dict[str, list[str]], namespace: str) -> None:
    module = importlib.import_module(namespace)
    entries = sections.get(namespace, [])
    missing = [
        name
        for name in public_names(namespace)
        if not any(
            entry.rpartition(".")[2] == name and pkgutil.resolve_name(entry) is getattr(module, name)
            for entry in entries
        )
    ]
    assert not missing, f"docs/api: {namespace} lists no entry for {missing}"


@pytest.mark.parametrize("namespace", DOCUMENTED)
def test_every_entry_is_a_public_name(sections: dict[str, list[str]], namespace: str) -> None:
    public = set(public_names(namespace))
    extra = [entry for entry in sections.get(namespace, []) if entry.rpartition(".")[2] not in public]
    assert not extra, f"docs/api: {namespace} lists {extra}, not among its public names"


def test_every_part_of_the_package_is_documented_or_internal() -> None:
    parts = {info.name for info in pkgutil.iter_modules(pmht_opt.__path__)}
    documented = {name.split(".")[1] for name in DOCUMENTED if name.count(".") == 1}
    undecided = sorted(parts - documented - set(INTERNAL))
    assert not undecided, f"pmht_opt.{undecided}: give each a page in docs/api/ or list it in INTERNAL"
    assert not (documented & set(INTERNAL))
    assert not (set(INTERNAL) - parts), "INTERNAL names a part that no longer exists"


def _python_blocks(path: Path) -> list[str]:
    return re.findall(r"```python\n(.*?)```", path.read_text(), re.S)


@pytest.mark.parametrize("page", ["docs/solvers.md"])
def test_the_python_examples_run_as_written(
    page: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Each page's Python blocks run in order, in a fresh namespace, writing into a scratch directory."""
    blocks = _python_blocks(Path(__file__).resolve().parents[1] / page)
    assert blocks, f"{page} has no python block"
    monkeypatch.chdir(tmp_path)
    namespace: dict[str, object] = {}
    for block in blocks:
        exec(compile(block, page, "exec"), namespace)


def test_the_readme_library_example_covers_every_locale(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """What the README's comments promise of its example: full coverage, no violation, a figure."""
    block = _python_blocks(Path(__file__).resolve().parents[1] / "README.md")[0]
    monkeypatch.chdir(tmp_path)
    namespace: dict[str, object] = {}
    exec(compile(block, "README.md", "exec"), namespace)
    result = namespace["result"]
    assert isinstance(result, pmht_opt.PlanResult)
    assert result.coverage(0.3) == 1.0 and result.max_violation <= 1e-6  # clarabel's tolerance
    # The distance its comment quotes, to the M-step's accuracy (the tour is the same on any machine).
    assert result.total_distance == pytest.approx(61.76, abs=0.005)
    assert (tmp_path / "paths.png").stat().st_size > 0
