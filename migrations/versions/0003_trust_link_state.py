"""trust at sea: packet authentication state, verified telemetry, staged keys, per-vehicle link state

Revision ID: 0003
Revises: 0002
"""

from collections.abc import Sequence

import sqlalchemy as sa
import sqlmodel
from alembic import op

revision: str = "0003"
down_revision: str | None = "0002"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("vehicle", schema=None) as batch_op:
        batch_op.add_column(sa.Column("previous_key_hex", sqlmodel.sql.sqltypes.AutoString(length=128),
                                      nullable=True))  # fmt: skip
    with op.batch_alter_table("packet", schema=None) as batch_op:
        batch_op.add_column(sa.Column("auth", sqlmodel.sql.sqltypes.AutoString(length=16),
                                      server_default="pending", nullable=False))  # fmt: skip
    with op.batch_alter_table("telemetry", schema=None) as batch_op:
        batch_op.add_column(sa.Column("verified", sa.Boolean(), server_default="0", nullable=False))
        batch_op.create_index(batch_op.f("ix_telemetry_packet_id"), ["packet_id"], unique=False)
    op.create_table(
        "linkstate",
        sa.Column("vehicle_id", sa.Integer(), nullable=False),
        sa.Column("state", sa.JSON(), nullable=False),
        sa.Column("updated_at", sa.Float(), nullable=False),
        sa.ForeignKeyConstraint(["vehicle_id"], ["vehicle.id"]),
        sa.PrimaryKeyConstraint("vehicle_id"),
    )


def downgrade() -> None:
    op.drop_table("linkstate")
    with op.batch_alter_table("telemetry", schema=None) as batch_op:
        batch_op.drop_index(batch_op.f("ix_telemetry_packet_id"))
        batch_op.drop_column("verified")
    with op.batch_alter_table("packet", schema=None) as batch_op:
        batch_op.drop_column("auth")
    with op.batch_alter_table("vehicle", schema=None) as batch_op:
        batch_op.drop_column("previous_key_hex")
