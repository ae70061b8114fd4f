"""The safety functions' state: each vehicle's planned path and the separation warnings now."""

from __future__ import annotations

from fastapi import APIRouter, Depends

from server.api.deps import SafetyDep, require_read
from server.safety.schemas import SafetyOut

router = APIRouter(prefix="/api/v1", tags=["safety"])


@router.get("/safety", response_model=SafetyOut, dependencies=[Depends(require_read)])
def safety(separation: SafetyDep) -> SafetyOut:
    """Each vehicle's planned path (predicted position to target, with its uncertainty) and the pairs
    of vehicles whose predicted positions are within the separation plus both uncertainties; the same
    warnings come as ``separation`` events on the event stream when they begin and end."""
    return SafetyOut.model_validate(
        {
            "separation_m": separation.settings.separation,
            "warnings": separation.warnings(),
            "paths": [p.as_dict() for p in separation.paths()],
        }
    )
