"""a gateway found faulty (why, when) and the reports it made of other gateways' commands; routing
counts a gateway's copy of a frame only if the frame verified (a tag or a MAC, a packet's first copy):
relayedframe.verified; a command's history says where each step came from (an operator, the
center, the shore's modem, a gateway, the vehicle's check-point) and through or by whom: commandevent's
source and via

Revision ID: 0017
Revises: 0016
"""

from collections.abc import Sequence

import sqlalchemy as sa
import sqlmodel
from alembic import op

revision: str = "0017"
down_revision: str | None = "0016"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("gateway", schema=None) as batch_op:
        batch_op.add_column(
            sa.Column(
                "faulty", sqlmodel.sql.sqltypes.AutoString(length=256), server_default="", nullable=False
            )
        )
        batch_op.add_column(sa.Column("faulty_at", sa.Float(), nullable=True))
        batch_op.add_column(sa.Column("foreign_reports", sa.Integer(), server_default="0", nullable=False))
    with op.batch_alter_table("relayedframe", schema=None) as batch_op:
        batch_op.add_column(sa.Column("verified", sa.Boolean(), server_default="0", nullable=False))
    with op.batch_alter_table("commandevent", schema=None) as batch_op:
        batch_op.add_column(
            sa.Column(
                "source", sqlmodel.sql.sqltypes.AutoString(length=16), server_default="shore", nullable=False
            )
        )
        batch_op.add_column(
            sa.Column("via", sqlmodel.sql.sqltypes.AutoString(length=64), server_default="", nullable=False)
        )


def downgrade() -> None:
    with op.batch_alter_table("commandevent", schema=None) as batch_op:
        batch_op.drop_column("via")
        batch_op.drop_column("source")
    with op.batch_alter_table("relayedframe", schema=None) as batch_op:
        batch_op.drop_column("verified")
    with op.batch_alter_table("gateway", schema=None) as batch_op:
        batch_op.drop_column("foreign_reports")
        batch_op.drop_column("faulty_at")
        batch_op.drop_column("faulty")
