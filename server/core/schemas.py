"""What every request and response body shares.

Every request body refuses NaN and +-Infinity (JSON has no such numbers, but Python's parser reads
``NaN``, ``Infinity`` and ``1e999`` into them): a 422 names the field. Strings and lists are bounded.
``json_safe`` makes anything echoed back in an error body encodable (non-finite floats as text).
"""

from __future__ import annotations

import math
from typing import Any, Generic, TypeVar

from pydantic import BaseModel, ConfigDict

# Request bodies: unknown fields and non-finite numbers are errors.
STRICT = ConfigDict(extra="forbid", allow_inf_nan=False)
DB_INT_MAX = 2**31 - 1  # what every database's INTEGER holds: larger ids cannot exist, say 422 not 500


class Problem(BaseModel):
    """Every error's body: what is wrong, and the field at fault (``server.core.errors``)."""

    detail: str
    field: str | None = None
    errors: list[dict[str, Any]] | None = None  # a request its schema refused: every fault found in it


T = TypeVar("T")


class Page(BaseModel, Generic[T]):
    total: int
    limit: int
    offset: int
    items: list[T]


def json_safe(value: Any) -> Any:
    """``value`` with every non-finite float as text and anything else JSON cannot hold as ``str``."""
    if isinstance(value, float):
        return value if math.isfinite(value) else str(value)
    if isinstance(value, (str, int, bool, type(None))):
        return value
    if isinstance(value, dict):
        return {str(k): json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_safe(v) for v in value]
    return str(value)
