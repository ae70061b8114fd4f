"""Configuration files: an unknown key is a typo the user must hear about, not a silent default."""

from __future__ import annotations

import dataclasses
from typing import Any


def check_keys(where: str, data: dict[str, Any], cls: type) -> None:
    """Raise ``ValueError`` naming every key of ``data`` that ``cls`` (a dataclass) has no field for."""
    unknown = set(data) - {f.name for f in dataclasses.fields(cls)}
    if unknown:
        raise ValueError(f"{where}: unknown settings {sorted(unknown)}")
