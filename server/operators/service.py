"""Operators: each person's own bearer token, created by an operator, listed without tokens, revoked at
once. ``Operators.actor`` is the one rule that turns a token into an ``Actor``: the settings' tokens
first (constant time), then this table by the token's SHA-256."""

from __future__ import annotations

import hashlib
import secrets
from datetime import UTC, datetime

from sqlalchemy import Engine

from server.core.config import Settings
from server.core.db import now, reading, writing
from server.core.errors import Conflict, NotFound, Refused, Unauthorized
from server.core.security import Actor, Role, configured
from server.operators import repository as repo
from server.operators.models import Operator
from server.operators.schemas import OperatorIn

RESERVED = "config-"  # the settings' tokens' names: config-operator-N, config-observer-N


def digest(token: str) -> str:
    """What the table keeps of a token: a random 24-byte token needs no salt nor slow hash."""
    return hashlib.sha256(token.encode()).hexdigest()


def _when(at: float) -> str:
    return datetime.fromtimestamp(at, UTC).isoformat(timespec="seconds")


def _accepted(operator: Operator, at: float) -> Actor:
    """The operator's actor, or ``Unauthorized`` saying when its token was revoked or expired."""
    if operator.revoked_at is not None:
        raise Unauthorized(f"this token was revoked at {_when(operator.revoked_at)}")
    if operator.expires_at is not None and operator.expires_at <= at:
        raise Unauthorized(
            f"this token expired at {_when(operator.expires_at)}; ask an operator for a new one"
        )
    return Actor(operator.name, Role(operator.role), operator.expires_at)  # the table holds its text


class Operators:
    def __init__(self, settings: Settings, db: Engine) -> None:
        self.settings = settings
        self.db = db

    def actor(self, token: str) -> Actor | None:
        """Who holds ``token``: None for a token nobody holds; ``Unauthorized`` if it expired or was
        revoked."""
        found = configured(self.settings, token)
        if found is not None:
            return found
        with reading(self.db) as s:
            operator = repo.by_hash(s, digest(token))
        return None if operator is None else _accepted(operator, now())

    def create(self, body: OperatorIn, creator: Actor) -> tuple[Operator, str]:
        """A new operator and its token (returned this once: only its hash is stored). A token never
        outlives its creator's: an operator whose own token expires cannot create one that expires later
        or never (only an operator creates tokens at all: ``require_write``)."""
        if body.name.startswith(RESERVED):
            raise Refused(f"names starting with {RESERVED!r} belong to the settings' tokens", "name")
        token = secrets.token_urlsafe(24)
        created = now()
        expires = None if body.expires_in_s is None else created + body.expires_in_s
        if creator.expires_at is not None and (expires is None or expires > creator.expires_at):
            raise Refused(
                f"your token expires at {_when(creator.expires_at)}: a token you create may not outlive it "
                f"(expires_in_s at most {max(0, int(creator.expires_at - created))})",
                "expires_in_s",
            )
        with writing(self.db) as s:
            if repo.by_name(s, body.name) is not None:
                raise Conflict(f"an operator named {body.name!r} exists", "name")
            operator = Operator(
                name=body.name,
                role=body.role,
                token_hash=digest(token),
                created_at=created,
                expires_at=expires,
                created_by=creator.name,
            )
            return repo.save(s, operator), token

    def every(self) -> list[Operator]:
        with reading(self.db) as s:
            return repo.every(s)

    def revoke(self, operator_id: int) -> Operator:
        """Revoke at once: the next request with its token is refused (revoking twice keeps the first
        time)."""
        with writing(self.db) as s:
            operator = repo.get(s, operator_id)
            if operator is None:
                raise NotFound(f"no operator {operator_id}", "operator_id")
            if operator.revoked_at is None:
                operator.revoked_at = now()
                repo.save(s, operator)
            return operator
