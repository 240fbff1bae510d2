"""The import graph: every module imports first in a fresh interpreter, and no import circle.

A circle of imports works only in the order the tests happen to load it (the first module of the
circle must be imported first), so each module of `app`, `control` and `robots` is imported here
in a process that has loaded no module of the project, and the graph of the project's imports
(`grimp`, which `lint-imports` uses for the contracts in `pyproject.toml`) must have no circle. An
import of `a.b.c` also runs the packages `a` and `a.b`, so an edge to a module is also an edge to
the packages above it (a circle through a package's `__init__` is a circle).
"""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import grimp

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("app", "control", "robots")
# modules that run in another environment, with the package they need there
OTHER_ENVIRONMENT = {"app.tools.placo_peer": "placo"}  # `torquelab bench --vs-placo PYTHON` runs it


def project_modules() -> list[str]:
    """Every module of the project, by file (nothing imported to find them)."""
    names = []
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            names.append(".".join(parts[:-1] if parts[-1] == "__init__" else parts))
    return names


# One driver process imports only the standard library and the third-party packages (their load
# time is not the question), then forks a child per module: each child starts with no module of the
# project loaded (it checks), imports its module and exits; the driver prints the failures.
DRIVER = textwrap.dedent(
    """
    import os, sys, traceback
    for name in ("numpy", "scipy", "scipy.linalg", "pinocchio", "numba", "mujoco", "viser", "matplotlib"):
        try:
            __import__(name)
        except ImportError:
            pass
    PROJECT = ("app", "control", "robots", "static", "tests")
    failures = 0
    for module in sys.argv[1:]:
        pid = os.fork()
        if pid == 0:
            loaded = [m for m in sys.modules if m.split(".")[0] in PROJECT]
            code = 3 if loaded else 0
            if not loaded:
                try:
                    __import__(module)
                except BaseException:
                    traceback.print_exc(limit=-3)
                    code = 1
            sys.stdout.flush(); sys.stderr.flush()
            os._exit(code)
        _, status = os.waitpid(pid, 0)
        code = os.waitstatus_to_exitcode(status)
        if code:
            failures += 1
            print(f"FAILED {module}: exit {code}" + (" (project modules already loaded)" if code == 3 else ""))
    sys.exit(1 if failures else 0)
    """
)


def test_every_module_imports_first_in_a_fresh_interpreter():
    modules = [
        m
        for m in project_modules()
        if not (m in OTHER_ENVIRONMENT and importlib.util.find_spec(OTHER_ENVIRONMENT[m]) is None)
    ]
    assert len(modules) >= 140  # the files were found
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    run = subprocess.run(
        [sys.executable, "-c", DRIVER, *modules], cwd=ROOT, capture_output=True, text=True, env=env, timeout=900
    )
    assert run.returncode == 0, run.stdout[-4000:] + run.stderr[-4000:]


def runtime_edges(direct: dict[str, set[str]]) -> dict[str, set[str]]:
    """The imports that run when each module is imported: its direct imports and the packages above
    each of them, except the packages the importing module is inside (already running)."""

    def packages_above(module: str) -> list[str]:
        parts = module.split(".")
        return [".".join(parts[:i]) for i in range(1, len(parts))]

    edges: dict[str, set[str]] = {}
    for a, imported in direct.items():
        out = set(imported)
        for b in imported:
            out.update(p for p in packages_above(b) if p in direct and not (a == p or a.startswith(p + ".")))
        edges[a] = out
    return edges


def _project_edges() -> dict[str, set[str]]:
    # imports under `if TYPE_CHECKING:` never run: a type named both ways is no circle of imports
    graph = grimp.build_graph(*PACKAGES, exclude_type_checking_imports=True, cache_dir=None)
    modules = set(graph.modules)
    return runtime_edges({m: graph.find_modules_directly_imported_by(m) & modules for m in modules})


def circles(edges: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan's algorithm, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    for root in sorted(edges):
        if root in index:
            continue
        work = [(root, iter(sorted(edges[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            v, children = work[-1]
            w = next(children, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(edges[w]))))
                elif w in on_stack:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                component = []
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    component.append(w)
                    if w == v:
                        break
                if len(component) > 1:
                    found.append(sorted(component))
    return found


def test_circles_finds_a_circle_through_a_package():
    # p.a imports p.k.x, which runs the package p.k, whose __init__ imports p.k.y, which imports p.a
    # (the shape of the circle gains → qp → kernels.dense_qp ⇒ kernels/__init__ → cqp → gains)
    direct = {"p": set(), "p.a": {"p.k.x"}, "p.k": {"p.k.y"}, "p.k.x": set(), "p.k.y": {"p.a"}}
    assert circles(direct) == []  # not seen from the import statements alone
    assert circles(runtime_edges(direct)) == [["p.a", "p.k", "p.k.y"]]
    # a package importing its own modules, and they the package's siblings, is no circle
    assert circles(runtime_edges({"p": set(), "p.k": {"p.k.x"}, "p.k.x": {"p.a"}, "p.a": set()})) == []


def test_the_import_graph_has_no_circle():
    edges = _project_edges()
    assert len(edges) >= 140
    assert circles(edges) == []
