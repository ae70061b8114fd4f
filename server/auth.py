"""Bearer tokens: operators (write) and observers (read). Compared in constant time, never logged."""

from __future__ import annotations

import hmac

from fastapi import Depends, HTTPException, status
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from server.api.deps import SettingsDep
from server.settings import Settings

bearer = HTTPBearer(auto_error=False, description="Authorization: Bearer <token>. Operators' tokens may "
                    "write (commands, missions, vehicles); observers' tokens only read.")  # fmt: skip


def _matches(token: str, candidates: list[str]) -> bool:
    found = False
    for candidate in candidates:  # no early exit: the time does not depend on which token matched
        found |= hmac.compare_digest(token.encode(), candidate.encode())
    return found


def role(settings: Settings, token: str | None) -> str | None:
    """``write`` for an operator's token, ``read`` for an observer's, None for anything else."""
    if token is None:
        return None
    if _matches(token, settings.write_tokens):
        return "write"
    if _matches(token, settings.read_tokens):
        return "read"
    return None


def _token(credentials: HTTPAuthorizationCredentials | None) -> str | None:
    return credentials.credentials if credentials is not None else None


def require_read(
    settings: SettingsDep, credentials: HTTPAuthorizationCredentials | None = Depends(bearer)
) -> str:
    """Reads are open when no tokens are configured at all (a bench setup); otherwise any valid token."""
    if not settings.write_tokens and not settings.read_tokens:
        return "write"
    found = role(settings, _token(credentials))
    if found is None:
        raise HTTPException(status.HTTP_401_UNAUTHORIZED, "a valid bearer token is required",
                            headers={"WWW-Authenticate": "Bearer"})  # fmt: skip
    return found


def require_write(
    settings: SettingsDep, credentials: HTTPAuthorizationCredentials | None = Depends(bearer)
) -> str:
    found = role(settings, _token(credentials))
    if found is None:
        raise HTTPException(status.HTTP_401_UNAUTHORIZED, "an operator's bearer token is required",
                            headers={"WWW-Authenticate": "Bearer"})  # fmt: skip
    if found != "write":
        raise HTTPException(status.HTTP_403_FORBIDDEN, "this token may only read")
    return found
