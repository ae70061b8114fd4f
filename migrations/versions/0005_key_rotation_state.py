"""a staged key rotation's state on the vehicle: since when it waits, and how many probe SYNCs (signed
with the new key) went out

Revision ID: 0005
Revises: 0004
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0005"
down_revision: str | None = "0004"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("vehicle", schema=None) as batch_op:
        batch_op.add_column(sa.Column("rotation_since", sa.Float(), nullable=True))
        batch_op.add_column(sa.Column("rotation_probes", sa.Integer(), server_default="0", nullable=False))


def downgrade() -> None:
    with op.batch_alter_table("vehicle", schema=None) as batch_op:
        batch_op.drop_column("rotation_probes")
        batch_op.drop_column("rotation_since")
