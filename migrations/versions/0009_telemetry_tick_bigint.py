"""telemetry.tick is a BIGINT: a tick is UNIX time over the stream's period (7e9 for the IMU's 0.25 s
today), beyond PostgreSQL's INTEGER (SQLite's integers were 64-bit already)

Revision ID: 0009
Revises: 0008
"""

from collections.abc import Sequence

import sqlalchemy as sa
from alembic import op

revision: str = "0009"
down_revision: str | None = "0008"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    with op.batch_alter_table("telemetry") as batch:
        batch.alter_column("tick", existing_type=sa.Integer(), type_=sa.BigInteger(), existing_nullable=False)


def downgrade() -> None:
    with op.batch_alter_table("telemetry") as batch:
        batch.alter_column("tick", existing_type=sa.BigInteger(), type_=sa.Integer(), existing_nullable=False)
