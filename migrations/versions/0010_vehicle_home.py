"""each vehicle's home in the fleet's one frame (north, east of the fleet's origin): where its mission's
waypoints, its return home and its geofence are centred

Revision ID: 0010
Revises: 0009
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0010"
down_revision: str | None = "0009"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("vehicle", schema=None) as batch_op:
        batch_op.add_column(sa.Column("home_north", sa.Float(), server_default="0", nullable=False))
        batch_op.add_column(sa.Column("home_east", sa.Float(), server_default="0", nullable=False))


def downgrade() -> None:
    with op.batch_alter_table("vehicle", schema=None) as batch_op:
        batch_op.drop_column("home_east")
        batch_op.drop_column("home_north")
