"""The shape of the code: no module imports itself back round a loop, and the layers hold.

``lint-imports`` (CI) checks the layer contracts of ``pyproject.toml``; the first test here checks
what a layers contract cannot see: loops inside one layer or one package. The second runs the
contracts themselves, so that a developer's ``pytest`` sees a broken layer too.
"""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Iterable
from pathlib import Path

import grimp

ROOT = Path(__file__).resolve().parent.parent


def strongly_connected(nodes: Iterable[str], edges: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of the directed graph (Tarjan's algorithm, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []
    counter = 0
    for root in nodes:
        if root in index:
            continue
        work = [(root, iter(sorted(edges.get(root, ()))))]
        index[root] = low[root] = counter
        counter += 1
        stack.append(root)
        on_stack.add(root)
        while work:
            v, children = work[-1]
            w = next(children, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(edges.get(w, ())))))
                elif w in on_stack:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                comp = []
                while True:
                    x = stack.pop()
                    on_stack.discard(x)
                    comp.append(x)
                    if x == v:
                        break
                out.append(comp)
    return out


def test_the_cycle_finder_finds_a_cycle() -> None:
    edges = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    loops = [sorted(c) for c in strongly_connected("abcd", edges) if len(c) > 1]
    assert loops == [["a", "b", "c"]]


def test_no_module_imports_itself_back() -> None:
    graph = grimp.build_graph("pmht_opt", "solvers", "studies", include_external_packages=False)
    modules = sorted(graph.modules)
    edges = {m: set(graph.find_modules_directly_imported_by(m)) for m in modules}
    loops = [sorted(c) for c in strongly_connected(modules, edges) if len(c) > 1]
    assert not loops, f"modules importing each other round a loop: {loops}"


def test_the_layer_contracts_hold() -> None:
    lint = Path(sys.executable).parent / "lint-imports"
    done = subprocess.run([str(lint), "--no-cache"], capture_output=True, text=True, cwd=ROOT)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-2000:]
    assert "pmht_opt is layered KEPT" in done.stdout and " 0 broken" in done.stdout, done.stdout[-2000:]


def test_a_foreign_package_named_solvers_is_named_not_used(tmp_path: Path) -> None:
    """Another project's top-level ``solvers`` found first: importing pmht_opt says so at once."""
    (tmp_path / "solvers").mkdir()
    (tmp_path / "solvers" / "__init__.py").write_text("VERSION = 1\n")
    env_path = f"{tmp_path}{':' + str(ROOT)}"
    done = subprocess.run(
        [sys.executable, "-c", "import pmht_opt"],
        capture_output=True,
        text=True,
        cwd=tmp_path,
        env={"PYTHONPATH": env_path, "PATH": ""},
    )
    assert done.returncode != 0
    assert "is not pmht-opt's generic QP layer" in done.stderr and str(tmp_path) in done.stderr


def test_no_module_of_the_library_is_over_450_lines() -> None:
    root = Path(__file__).resolve().parents[1]
    long = {
        str(p.relative_to(root)): n
        for package in ("pmht_opt", "solvers")
        for p in (root / package).rglob("*.py")
        if (n := len(p.read_text().splitlines())) > 450
    }
    assert not long, long
