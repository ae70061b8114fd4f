"""Operator request and response bodies: the token appears once, in ``OperatorCreated``."""

from __future__ import annotations

from pydantic import BaseModel, Field

from server.core.schemas import STRICT
from server.core.security import Role

DEFAULT_LIFETIME_S = 12 * 3600.0  # a watch


class OperatorIn(BaseModel):
    model_config = STRICT
    name: str = Field(min_length=1, max_length=64, pattern=r"^[\w.@-]+$", description="a person")
    role: Role = Field(description="write (operator: commands, missions, vehicles) or read (observer)")
    expires_in_s: float | None = Field(
        DEFAULT_LIFETIME_S, gt=0, le=366 * 86400, description="s until the token expires; null: never"
    )


class OperatorOut(BaseModel):
    id: int
    name: str
    role: Role
    created_at: float
    created_by: str
    expires_at: float | None = Field(description="UNIX s; null: never")
    revoked_at: float | None = Field(description="UNIX s; null: not revoked")


class OperatorCreated(OperatorOut):
    token: str = Field(description="the bearer token: shown this once, never stored (only its hash)")
