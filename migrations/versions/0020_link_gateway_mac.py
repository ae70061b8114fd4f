"""gateway MAC: each gateway's MAC status from its heartbeats (exchanges, airtime, late turns, a refused
plan; range, rate and SNR per vehicle at that gateway)

Revision ID: 0020
Revises: 0019
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0020"
down_revision: str | None = "0019"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("gateway") as table:
        table.add_column(sa.Column("mac", sa.JSON(), nullable=True))


def downgrade() -> None:
    with op.batch_alter_table("gateway") as table:
        table.drop_column("mac")
