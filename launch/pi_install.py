"""docs/agent.md's install (``deploy/install-agent --root``) into a root file system as Raspberry Pi OS
starts (root and the dialout group, no service user): for the tests and ``bench/bench_agent_install.py``."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def fresh_root(where: Path) -> Path:
    (where / "etc").mkdir(parents=True)
    (where / "etc/passwd").write_text("root:x:0:0:root:/root:/bin/bash\n")
    (where / "etc/group").write_text("root:x:0:\ndialout:x:20:\n")
    (where / "etc/shadow").write_text("root:*:19000:0:99999:7:::\n")
    (where / "etc/gshadow").write_text("root:*::\ndialout:*::\n")
    return where


def install_agent(
    root: Path, *options: str, clone: Path = ROOT, env: dict[str, str] | None = None, timeout: float = 60
) -> subprocess.CompletedProcess[str]:
    """``deploy/install-agent --root ROOT OPTIONS`` from ``clone``."""
    assert os.geteuid() == 0, "the install makes a user and sets owners: run the tests as root, as CI does"
    return subprocess.run(
        [str(clone / "deploy/install-agent"), "--root", str(root), *options],
        capture_output=True,
        text=True,
        timeout=timeout,
        env=env,
    )
