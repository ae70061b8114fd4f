"""The operator table's SQL."""

from __future__ import annotations

from sqlmodel import Session, col, select

from server.operators.models import Operator


def get(s: Session, operator_id: int) -> Operator | None:
    return s.get(Operator, operator_id)


def by_name(s: Session, name: str) -> Operator | None:
    return s.exec(select(Operator).where(Operator.name == name)).first()


def by_hash(s: Session, token_hash: str) -> Operator | None:
    return s.exec(select(Operator).where(Operator.token_hash == token_hash)).first()


def every(s: Session) -> list[Operator]:
    return list(s.exec(select(Operator).order_by(col(Operator.id))))


def save(s: Session, operator: Operator) -> Operator:
    s.add(operator)
    s.commit()
    s.refresh(operator)
    return operator
