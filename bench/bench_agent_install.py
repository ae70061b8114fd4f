"""The vehicle agent's install on a Pi: its size on disk and the packages it pulls.

    .venv/bin/python bench/bench_agent_install.py

Installs twice into temporary folders, from this checkout, the packages of this machine's platform:
docs/agent.md's install (``deploy/install-agent --root``: ``deploy/agent-requirements.txt`` with
``--no-deps``, then Tacit) and, for comparison, ``pip install '.[agent]'`` with every dependency's own
dependencies. Prints each environment's size and the size of each package in it (the files its install
record lists, byte code included), and checks that the agent runs in the first. Needs root (the install
makes a user in the temporary root) and the package index; a few minutes.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from launch.pi_install import fresh_root, install_agent  # noqa: E402

SIZES = """
import importlib.metadata as m, json, sys
sizes = {}
for dist in m.distributions(path=sys.path[1:]):
    files = [dist.locate_file(f) for f in dist.files or []]
    sizes[dist.metadata["Name"]] = sum(f.stat().st_size for f in files if f.is_file())
print(json.dumps(sizes))
"""


def folder_size(path: Path) -> int:
    return sum(f.lstat().st_size for f in path.rglob("*") if f.is_file() and not f.is_symlink())


def packages(venv: Path) -> dict[str, int]:
    out = subprocess.run([str(venv / "bin/python"), "-c", SIZES], capture_output=True, text=True, check=True)
    return dict(sorted(json.loads(out.stdout).items(), key=lambda kv: -kv[1]))


def pi_install(where: Path) -> Path:
    root = fresh_root(where / "root")
    done = install_agent(root, timeout=1800)
    if done.returncode != 0:
        raise SystemExit(f"deploy/install-agent failed: {done.stderr}")
    return root / "opt/tacit/.venv"


def extra_install(where: Path) -> Path:
    venv = where / "extra"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    subprocess.run([str(venv / "bin/pip"), "install", "-q", f"{ROOT}[agent]"], check=True, timeout=1800)
    return venv


def check(venv: Path) -> None:
    """What the figures claim: the agent runs in the Pi's environment, which has no plotting package."""
    agent = subprocess.run([str(venv / "bin/tacit"), "agent", "--help"], capture_output=True, text=True)
    assert agent.returncode == 0, agent.stderr
    plotting = subprocess.run([str(venv / "bin/python"), "-c", "import matplotlib"], capture_output=True)
    assert plotting.returncode != 0, "matplotlib is in the Pi's environment"


def report(name: str, venv: Path) -> None:
    sizes = packages(venv)
    print(f"\n{name}: {folder_size(venv) / 1e6:.0f} MB, {len(sizes)} packages")
    for package, size in sizes.items():
        print(f"  {package:<20} {size / 1e6:7.1f} MB")


def main() -> None:
    argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    ).parse_args()
    with tempfile.TemporaryDirectory(prefix="tacit-agent-install-") as tmp:
        pi = pi_install(Path(tmp))
        check(pi)
        report("deploy/install-agent (docs/agent.md)", pi)
        report("pip install '.[agent]'", extra_install(Path(tmp)))


if __name__ == "__main__":
    main()
