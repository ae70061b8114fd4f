"""a staged key rotation follows the vehicle's word: whether its last check-point said it holds the new
key (commands and SYNCs are then signed with it) instead of a count of probe SYNCs

Revision ID: 0012
Revises: 0011
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0012"
down_revision: str | None = "0011"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("vehicle", schema=None) as batch_op:
        batch_op.add_column(
            sa.Column("next_key_held", sa.Boolean(), server_default=sa.false(), nullable=False)
        )
        batch_op.drop_column("rotation_probes")


def downgrade() -> None:
    with op.batch_alter_table("vehicle", schema=None) as batch_op:
        batch_op.add_column(sa.Column("rotation_probes", sa.Integer(), server_default="0", nullable=False))
        batch_op.drop_column("next_key_held")
