"""What the safety functions show: planned paths and separation warnings."""

from __future__ import annotations

from pydantic import BaseModel


class PathOut(BaseModel):
    vehicle: str
    start: list[float]
    end: list[float]
    radius_m: float


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
