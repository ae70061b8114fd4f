"""The operator table: a named person's bearer token (only its SHA-256 is kept), role, expiry and
revocation."""

from __future__ import annotations

from sqlmodel import AutoString, Field, SQLModel

from server.core.db import now
from server.core.security import Role


class Operator(SQLModel, table=True):
    id: int | None = Field(default=None, primary_key=True)
    name: str = Field(unique=True, max_length=64)
    role: Role = Field(sa_type=AutoString(16))
    token_hash: str = Field(unique=True, max_length=64)  # SHA-256 hex of the token, never the token
    created_at: float = Field(default_factory=now)
    expires_at: float | None = None  # None: never
    revoked_at: float | None = None
    created_by: str = Field(max_length=64)  # the operator who created it
