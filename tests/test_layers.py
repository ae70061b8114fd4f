"""The layers import one way: core <- apps (server, vehicle_agent) <- simulators, analysis <- launch.

The core (``tacit/``) runs on the vehicle's Raspberry Pi with three dependencies; the agent must not
pull in the web stack, the server not the vehicle's code. A wrong import is caught here, not on a
fresh machine.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
OURS = {"tacit", "server", "vehicle_agent", "simulators", "analysis", "launch", "tests", "bench"}
CORE_THIRD_PARTY = {"numpy", "filterpy", "serial"}

# package: the project's packages it may import
ALLOWED = {
    "tacit": {"tacit"},
    "server": {"tacit", "server"},
    "vehicle_agent": {"tacit", "vehicle_agent"},
    "simulators": {"tacit", "simulators", "analysis"},  # the tlog reader, to stream a real dive
    "analysis": {"tacit", "analysis"},
    "launch": {"tacit", "server", "vehicle_agent", "simulators", "analysis", "launch"},
    "bench": {"tacit", "server", "vehicle_agent", "simulators", "analysis", "launch", "bench"},
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


def test_the_checker_sees_a_wrong_import(tmp_path: Path) -> None:
    bad = tmp_path / "bad.py"
    bad.write_text("def later():\n    from server.app import create_app\n    import httpx\n")
    assert [m for _, m in imports(bad)] == ["server.app", "httpx"]


def test_the_mission_state_machine_needs_no_mavlink() -> None:
    """Algorithm 2 is plain logic: importing it must not import pymavlink (tested without I/O)."""
    code = "import sys, vehicle_agent.mission; print('pymavlink' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, check=True)
    assert out.stdout.strip() == "False"
