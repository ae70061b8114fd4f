"""deploy/agent-requirements.txt, the Pi's packages (installed with ``--no-deps``): it has every package
pyproject.toml gives the core and the agent, with the same bounds; the agent's modules import with these
packages alone, and import each of them."""

from __future__ import annotations

import json
import re
import subprocess
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]
RUNNING = """
import importlib.metadata, json, sys
names = importlib.metadata.packages_distributions()
listed = set(json.loads(sys.argv[1])) | {"tacit"}

class OnlyListed:  # any other package is missing, as on the Pi: what only tries it goes on without it
    def find_spec(self, name, path=None, target=None):
        dists = {d.lower() for d in names.get(name.split(".")[0], [])}
        if dists and not dists & listed:
            raise ModuleNotFoundError(f"{name} is not on the Pi", name=name)

before = set(sys.modules)
sys.meta_path.insert(0, OnlyListed())
import tacit.cli, tacit.modem.transport, vehicle_agent.agent, vehicle_agent.check
from pymavlink import mavutil
imported = {d.lower() for m in set(sys.modules) - before for d in names.get(m.split(".")[0], [])}
print(json.dumps(sorted(imported - {"tacit"})))
"""


def requirements() -> dict[str, str]:
    lines = (ROOT / "deploy/agent-requirements.txt").read_text().splitlines()
    specs = [line.split("#")[0].strip() for line in lines if line.split("#")[0].strip()]
    return {re.split(r"[<>=!~ ]", spec, maxsplit=1)[0].lower(): spec for spec in specs}


def test_it_has_the_core_and_the_agents_packages_with_their_bounds() -> None:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    declared = [*project["dependencies"], *project["optional-dependencies"]["agent"]]
    listed = requirements()
    for spec in declared:
        name = re.split(r"[<>=!~ ]", spec, maxsplit=1)[0].lower()
        assert listed.get(name) == spec, f"{spec} in pyproject.toml, {listed.get(name)} in the requirements"


def test_it_has_what_the_agent_imports_and_nothing_else() -> None:
    listed = json.dumps(sorted(requirements()))
    out = subprocess.run([sys.executable, "-c", RUNNING, listed], capture_output=True, text=True, cwd=ROOT)
    assert out.returncode == 0, out.stderr[-2000:]  # the agent's modules import with the listed packages
    assert set(json.loads(out.stdout)) == set(requirements())  # and each is imported
