"""Operators: an operator creates a person's token (shown once), lists them, revokes one at once."""

from __future__ import annotations

from fastapi import APIRouter, Depends

from server.api.deps import Id, OperatorsDep, Writer, require_write
from server.core import errors
from server.core.errors import Conflict
from server.operators.models import Operator
from server.operators.schemas import OperatorCreated, OperatorIn, OperatorOut

router = APIRouter(prefix="/api/v1", tags=["operators"])


def _out(operator: Operator) -> OperatorOut:
    return OperatorOut.model_validate(operator, from_attributes=True)


@router.post(
    "/operators", status_code=201, response_model=OperatorCreated, responses=errors.responses(Conflict)
)
def create_operator(body: OperatorIn, operators: OperatorsDep, actor: Writer) -> OperatorCreated:
    """A person's own token, which expires after ``expires_in_s`` (null: never), and never after the
    creator's own token (422 otherwise). The token is in this answer only: the shore keeps its hash, so a
    lost token is revoked and a new one created."""
    operator, token = operators.create(body, actor)
    return OperatorCreated(**_out(operator).model_dump(), token=token)


@router.get("/operators", response_model=list[OperatorOut], dependencies=[Depends(require_write)])
def list_operators(operators: OperatorsDep) -> list[OperatorOut]:
    """Every operator and observer created through the API (the settings' tokens are not listed), with
    who created them, when they expire and whether they were revoked; never their tokens."""
    return [_out(o) for o in operators.every()]


@router.delete("/operators/{operator_id}", response_model=OperatorOut, dependencies=[Depends(require_write)])
def revoke_operator(operator_id: Id, operators: OperatorsDep) -> OperatorOut:
    """Revoke the token at once: its next request gets 401 "this token was revoked at ..."."""
    return _out(operators.revoke(operator_id))
