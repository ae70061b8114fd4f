"""Configuration files: an unknown key is a typo the user must hear about, not a silent default."""

from __future__ import annotations

import dataclasses
import json
import os
from typing import Any


def check_keys(where: str, data: dict[str, Any], cls: type) -> None:
    """Raise ``ValueError`` naming every key of ``data`` that ``cls`` (a dataclass) has no field for."""
    unknown = set(data) - {f.name for f in dataclasses.fields(cls)}
    if unknown:
        raise ValueError(f"{where}: unknown settings {sorted(unknown)}")


def dump_toml(data: dict[str, Any]) -> str:
    """``data`` as TOML: scalars, lists and nested tables (inline), every string escaped.

    The standard library reads TOML but does not write it; this writes the subset configuration files
    use. JSON string escapes are valid TOML basic-string escapes, so strings go through ``json.dumps``.
    """
    return "".join(f"{key} = {_toml_value(value)}\n" for key, value in data.items() if value is not None)


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int | float):
        if value != value or value in (float("inf"), float("-inf")):
            raise ValueError(f"TOML has no portable spelling for {value!r}")
        return repr(value)
    if isinstance(value, str | os.PathLike):
        return json.dumps(os.fspath(value))
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{json.dumps(str(k))} = {_toml_value(v)}" for k, v in value.items()) + "}"
    raise TypeError(f"cannot write {type(value).__name__} as TOML")
