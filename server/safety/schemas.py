"""What the safety functions show: planned paths and separation warnings."""

from __future__ import annotations

from pydantic import BaseModel, Field


class PathOut(BaseModel):
    vehicle: str
    start: list[float] = Field(description="where it is predicted now: north, east, depth (m)")
    end: list[float] = Field(description="where its plan ends")
    route: list[list[float]] = Field(description="the plan's line: its position, then each target in turn")
    radius_m: float = Field(description="the uncertainty about its position now")


class WarningOut(BaseModel):
    vehicles: list[str]
    distance_m: float
    limit_m: float
    separation_m: float
    uncertainty_m: float


class SafetyOut(BaseModel):
    separation_m: float
    warnings: list[WarningOut]
    paths: list[PathOut]
