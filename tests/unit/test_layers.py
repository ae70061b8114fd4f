"""The layers import one way: core <- gateway wing <- apps (server, vehicle_agent) <- simulators,
analysis <- launch.

The core (``tacit/``) runs on the vehicle's Raspberry Pi with three dependencies; the agent must not
pull in the web stack, the server not the vehicle's code. A wrong import is caught here, not on a
fresh machine.
"""

from __future__ import annotations

import ast
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
OURS = {"tacit", "gateway", "server", "vehicle_agent", "simulators", "analysis", "launch", "tests", "bench"}
CORE_THIRD_PARTY = {"numpy", "filterpy", "serial"}

# package: the project's packages it may import
ALLOWED = {
    "tacit": {"tacit"},
    "gateway": {"tacit", "gateway"},  # the MAC every shore modem's process runs: no web stack, no database
    "server": {"tacit", "gateway", "server"},
    "vehicle_agent": {"tacit", "vehicle_agent"},
    "simulators": {"tacit", "simulators", "analysis"},  # the tlog reader, to stream a real dive
    "analysis": {"tacit", "analysis"},
    "launch": {"tacit", "gateway", "server", "vehicle_agent", "simulators", "analysis", "launch"},
    "bench": {"tacit", "gateway", "server", "vehicle_agent", "simulators", "analysis", "launch", "bench"},
}


def imports(path: Path) -> list[tuple[int, str]]:
    """Every absolute import in ``path``, at any depth (lazy imports inside functions count too)."""
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found.append((node.lineno, node.module))
    return found


def violations(package: str) -> list[str]:
    bad = []
    for path in sorted((ROOT / package).rglob("*.py")):
        for line, module in imports(path):
            top = module.split(".")[0]
            if top in OURS and top not in ALLOWED[package]:
                bad.append(f"{path.relative_to(ROOT)}:{line} imports {module}")
            elif package == "tacit" and top not in OURS and top not in sys.stdlib_module_names:
                if top not in CORE_THIRD_PARTY:
                    bad.append(f"{path.relative_to(ROOT)}:{line} imports {module} (not a core dependency)")
    return bad


@pytest.mark.parametrize("package", sorted(ALLOWED))
def test_package_imports_only_the_layers_below_it(package: str) -> None:
    assert violations(package) == []


SERVER = ROOT / "server"
SQL_NAMES = {"Session", "select", "insert", "update", "delete", "func", "col", "text"}
SQL_MODULES = {"sqlmodel", "sqlalchemy", "sqlalchemy.orm", "sqlalchemy.sql", "sqlmodel.sql.expression"}
MAY_RUN_SQL = {"repository.py", "db.py"}  # a domain's repository; the database's own module


def server_modules() -> dict[str, Path]:
    return package_modules(SERVER)


def package_modules(package: Path) -> dict[str, Path]:
    """A package's modules by dotted name (a package by its own name, not ``__init__``)."""
    modules = {}
    for path in sorted(package.rglob("*.py")):
        if "migrations" in path.parts:
            continue
        parts = path.relative_to(ROOT).with_suffix("").parts
        modules[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return modules


def module_imports(path: Path, modules: dict[str, Path]) -> list[tuple[int, str]]:
    """The ``modules`` that ``path`` imports, ``from package import module`` resolved to the module."""
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            found += [
                (node.lineno, f"{node.module}.{alias.name}")
                if f"{node.module}.{alias.name}" in modules
                else (node.lineno, node.module)
                for alias in node.names
            ]
    return [(line, m) for line, m in found if m in modules]


def sql_imports(path: Path) -> list[str]:
    """The query-building names ``path`` imports (a Session, select, insert ...)."""
    found = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module in SQL_MODULES:
            found += [alias.name for alias in node.names if alias.name in SQL_NAMES]
    return found


def test_only_repositories_run_sql() -> None:
    bad = [
        f"{path.relative_to(ROOT)} imports {names}"
        for path in server_modules().values()
        if path.name not in MAY_RUN_SQL and (names := sql_imports(path))
    ]
    assert bad == []


def test_routes_and_screens_go_through_services() -> None:
    """Endpoints, the screens' routes and the map never reach a repository, a session or the link's
    internals (ingest, decoders) directly."""
    bad = []
    modules = server_modules()
    for name, path in modules.items():
        if name.endswith(".endpoints") or name.startswith("server.map"):
            for line, module in module_imports(path, modules):
                if module.endswith(".repository") or module in ("server.link.ingest", "server.link.state"):
                    bad.append(f"{path.relative_to(ROOT)}:{line} imports {module}")
    assert bad == []


@pytest.mark.parametrize("package", ["tacit", "server"])
def test_no_import_cycle(package: str) -> None:
    """Every import counts, those made only for type checking too: a cycle is a design that only runs
    because of the order things happen to be imported in."""
    modules = package_modules(ROOT / package)
    graph = {
        name: {m for _, m in module_imports(path, modules) if m != name} for name, path in modules.items()
    }
    cycles = [component for component in _strongly_connected(graph) if len(component) > 1]
    assert cycles == []


def _strongly_connected(graph: dict[str, set[str]]) -> list[list[str]]:
    """Tarjan's algorithm: the graph's strongly connected components."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    out: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        for nxt in graph[node]:
            if nxt not in index:
                visit(nxt)
                low[node] = min(low[node], low[nxt])
            elif nxt in stack:
                low[node] = min(low[node], index[nxt])
        if low[node] == index[node]:
            component = []
            while True:
                top = stack.pop()
                component.append(top)
                if top == node:
                    break
            out.append(component)

    for node in graph:
        if node not in index:
            visit(node)
    return out


def test_the_cycle_finder_sees_a_cycle() -> None:
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert [sorted(c) for c in _strongly_connected(graph) if len(c) > 1] == [["a", "b", "c"]]


def test_the_checker_sees_a_wrong_import(tmp_path: Path) -> None:
    bad = tmp_path / "bad.py"
    bad.write_text("def later():\n    from server.app import create_app\n    import httpx\n")
    assert [m for _, m in imports(bad)] == ["server.app", "httpx"]
