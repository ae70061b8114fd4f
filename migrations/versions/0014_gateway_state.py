"""gateway state: each gateway's place, modem, outbox and last outage, from its heartbeats (the screens)

Revision ID: 0014
Revises: 0013
"""

from collections.abc import Sequence

import sqlalchemy as sa
import sqlmodel
from alembic import op

revision: str = "0014"
down_revision: str | None = "0013"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

FLOATS = ("beating_since", "north", "east", "depth", "outage_s", "outage_ended")
INTEGERS = ("address", "outbox", "outage_backlog")


def upgrade() -> None:
    with op.batch_alter_table("gateway") as table:
        for name in FLOATS:
            table.add_column(sa.Column(name, sa.Float(), nullable=True))
        for name in INTEGERS:
            table.add_column(sa.Column(name, sa.Integer(), nullable=True))
        table.add_column(
            sa.Column("modem", sqlmodel.sql.sqltypes.AutoString(length=32), nullable=False, server_default="")
        )


def downgrade() -> None:
    with op.batch_alter_table("gateway") as table:
        for name in ("modem", *INTEGERS, *FLOATS):
            table.drop_column(name)
