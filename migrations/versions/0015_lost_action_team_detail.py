"""a vehicle's lost-link action (its agent's lost_action, then each set_param of it it executed): the
separation check counts where it takes the vehicle; a team mission's detail: why its start was refused

Revision ID: 0015
Revises: 0014
"""

from collections.abc import Sequence

import sqlalchemy as sa
import sqlmodel
from alembic import op

revision: str = "0015"
down_revision: str | None = "0014"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("vehicle", schema=None) as batch_op:
        batch_op.add_column(
            sa.Column(
                "lost_action",
                sqlmodel.sql.sqltypes.AutoString(length=16),
                server_default="hold",
                nullable=False,
            )
        )
    with op.batch_alter_table("teammission", schema=None) as batch_op:
        batch_op.add_column(
            sa.Column(
                "detail", sqlmodel.sql.sqltypes.AutoString(length=1024), server_default="", nullable=False
            )
        )


def downgrade() -> None:
    with op.batch_alter_table("teammission", schema=None) as batch_op:
        batch_op.drop_column("detail")
    with op.batch_alter_table("vehicle", schema=None) as batch_op:
        batch_op.drop_column("lost_action")
