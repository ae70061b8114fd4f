"""A vehicle's configuration checked before a dive: the example as installed lacks only the key; every
other mistake is one problem naming its setting, and nothing that is wrong is started."""

from __future__ import annotations

import configparser
import shutil
from pathlib import Path

from vehicle_agent import check

ROOT = Path(__file__).resolve().parents[3]
DEPLOY = ROOT / "deploy"
KEY = "ab" * 32


def installed_example(folder: Path, key: str = "PUT-THE-VEHICLE-KEY-HERE") -> Path:
    """deploy/agent.example.toml and deploy/missions as the install puts them (0640), writing into
    ``folder`` instead of /var, with ``key``."""
    folder.mkdir(exist_ok=True)
    config = folder / "agent.toml"
    text = (DEPLOY / "agent.example.toml").read_text()
    text = text.replace("/var/lib/tacit", str(folder / "state")).replace(
        "/var/log/tacit", str(folder / "log")
    )
    config.write_text(text.replace('"PUT-THE-VEHICLE-KEY-HERE"', f'"{key}"'))
    config.chmod(0o640)
    shutil.copytree(DEPLOY / "missions", folder / "missions")
    return config


def problems(config: Path) -> list[str]:
    return [str(p) for p in check.load(config).problems]


def test_the_installed_example_lacks_only_the_vehicles_key(tmp_path: Path) -> None:
    config = installed_example(tmp_path)
    assert [p.split(":")[0] for p in problems(config)] == ["key"]
    loaded = check.load(installed_example(tmp_path / "keyed", KEY))
    assert loaded.problems == []
    assert {n: p.name for n, p in loaded.plans.items()} == {1: "square", 2: "lawnmower", 3: "transect"}


def test_each_mistake_is_one_line_naming_its_setting(tmp_path: Path) -> None:
    (tmp_path / "a-file").write_text("")
    (tmp_path / "far.json").write_text(
        '{"name": "far", "number": 4, "waypoints": [{"north": 0, "east": 0, "depth": 2}, '
        '{"north": 600, "east": 0, "depth": 2}]}'
    )
    config = tmp_path / "agent.toml"
    config.write_text(
        f'key = "{KEY}"\nnext_key = "{KEY}"\nkey_version = 0\naddress = 1\ncheckpoint_interval = -5\n'
        'lost_action = "panic"\n'
        f'state_file = "{tmp_path}/a-file/state.json"\n'
        'missions = [{builtin = "square", number = 1}, {builtin = "spiral"}, {file = "gone.json"}, '
        '{file = "far.json"}, {builtin = "lawnmower", number = 1}, {builtin = "square", number = 6, depth = 80.0}]\n'
        "[limits]\nmax_depth = 50.0\ngeofence_radius = 500.0\nmax_speed = 0\n"
    )
    config.chmod(0o600)
    found = problems(config)
    assert len(found) == 12, found
    assert all("\n" not in p for p in found)
    assert {p.split(":")[0] for p in found} == {
        "next_key", "key_version", "address", "checkpoint_interval", "lost_action", "state_file",
        "limits.max_speed", "missions[1]", "missions[2]", "missions[3]", "missions[4]", "missions[5]",
    }  # fmt: skip
    joined = "\n".join(found)
    assert "no built-in mission 'spiral'" in joined and "gone.json" in joined
    assert "outside the 500 m geofence" in joined and "80.00 m is outside 0 .. 50.0 m" in joined
    assert "mission number 1 is also square's" in joined


def test_a_wrong_type_an_unknown_setting_or_not_toml_is_named(tmp_path: Path) -> None:
    config = tmp_path / "agent.toml"
    config.write_text(f'key = "{KEY}"\naddress = "two"\n[nav]\ncruise_speed = "fast"\n')
    config.chmod(0o600)
    assert problems(config) == [
        "address: must be a whole number, not 'two'",
        "nav.cruise_speed: must be a number, not 'fast'",
    ]
    config.write_text(f'key = "{KEY}"\n[limits]\nmax_dept = 5.0\n')
    assert problems(config) == [f"config: {config} [limits]: unknown settings ['max_dept']"]
    config.write_text("key = \n")
    assert problems(config)[0].startswith(f"config: {config} is not TOML")
    assert problems(tmp_path / "none.toml") == [
        f"config: cannot read {tmp_path / 'none.toml'}: No such file or directory"
    ]


def test_a_key_every_user_may_read_is_a_problem(tmp_path: Path) -> None:
    config = installed_example(tmp_path, KEY)
    config.chmod(0o644)
    assert problems(config) == [
        f"config: {config} is readable by every user: chmod 640 {config} (it holds the key)"
    ]


def test_the_unit_does_not_restart_an_agent_that_refused_its_configuration() -> None:
    unit = configparser.ConfigParser(strict=False)
    unit.read(DEPLOY / "tacit-agent.service")
    service = unit["Service"]
    assert service["Restart"] == "always"
    assert str(check.EXIT_CONFIG) in service["RestartPreventExitStatus"].split()
    assert service["User"] == "tacit" and "dialout" in service["SupplementaryGroups"].split()
