"""the shore's own bookkeeping of a priority packet as columns: origin (the packet its decoder state came
from) and trusted (its data may be believed), moved out of the packet's JSON body

Revision ID: 0004
Revises: 0003
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0004"
down_revision: str | None = "0003"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None

packet = sa.table("packet", sa.column("id", sa.Integer), sa.column("type", sa.String), sa.column("body", sa.JSON),
                  sa.column("origin", sa.Integer), sa.column("trusted", sa.Boolean))  # fmt: skip


def upgrade() -> None:
    with op.batch_alter_table("packet", schema=None) as batch_op:
        batch_op.add_column(sa.Column("origin", sa.Integer(), nullable=True))
        batch_op.add_column(sa.Column("trusted", sa.Boolean(), server_default="0", nullable=False))
    connection = op.get_bind()
    rows = connection.execute(sa.select(packet.c.id, packet.c.body).where(packet.c.type == "priority")).all()
    for packet_id, body in rows:
        body = dict(body or {})
        origin, trusted = body.pop("origin", None), bool(body.pop("trusted", False))
        connection.execute(sa.update(packet).where(packet.c.id == packet_id)
                           .values(origin=origin, trusted=trusted, body=body))  # fmt: skip


def downgrade() -> None:
    with op.batch_alter_table("packet", schema=None) as batch_op:
        batch_op.drop_column("trusted")
        batch_op.drop_column("origin")
