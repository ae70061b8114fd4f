"""the center's record of frames that came over the backhaul (issue 24): one row per message id (the
store's de-duplication), pointing at the frame row it became; copies of one frame heard by several
gateways point at the same row

Revision ID: 0006
Revises: 0005
"""

from collections.abc import Sequence

import sqlalchemy as sa
import sqlmodel
from alembic import op

revision: str = "0006"
down_revision: str | None = "0005"
branch_labels: str | Sequence[str] | None = None
depends_on: str | Sequence[str] | None = None


def upgrade() -> None:
    op.create_table(
        "relayedframe",
        sa.Column("id", sqlmodel.sql.sqltypes.AutoString(length=128), nullable=False),
        sa.Column("frame_id", sa.Integer(), nullable=True),
        sa.Column("gateway", sqlmodel.sql.sqltypes.AutoString(length=64), nullable=False),
        sa.Column("src", sa.Integer(), nullable=False),
        sa.Column("digest", sqlmodel.sql.sqltypes.AutoString(length=64), nullable=False),
        sa.Column("snr_in", sa.Float(), nullable=True),
        sa.Column("at", sa.Float(), nullable=False),
        sa.Column("received_at", sa.Float(), nullable=False),
        sa.Column("kept", sa.Boolean(), nullable=False),
        sa.ForeignKeyConstraint(["frame_id"], ["frame.id"], ondelete="SET NULL"),
        sa.PrimaryKeyConstraint("id"),
    )
    op.create_index("ix_relayedframe_frame_id", "relayedframe", ["frame_id"])
    op.create_index("ix_relayedframe_gateway", "relayedframe", ["gateway"])
    op.create_index("ix_relayedframe_src_digest", "relayedframe", ["src", "digest"])


def downgrade() -> None:
    op.drop_index("ix_relayedframe_src_digest", table_name="relayedframe")
    op.drop_index("ix_relayedframe_gateway", table_name="relayedframe")
    op.drop_index("ix_relayedframe_frame_id", table_name="relayedframe")
    op.drop_table("relayedframe")
