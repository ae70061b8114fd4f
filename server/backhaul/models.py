"""The center's record of every frame that came over the backhaul: its message id (unique: the store's
own de-duplication, which no broker window bounds), the gateway that heard it, and the frame row it
became. Two gateways hearing one transmission make two rows pointing at one frame: ``heard_by``."""

from __future__ import annotations

from sqlalchemy import Column, ForeignKey, Index, Integer
from sqlmodel import Field, SQLModel

from server.core.db import now


class RelayedFrame(SQLModel, table=True):
    __tablename__ = "relayedframe"
    __table_args__ = (Index("ix_relayedframe_src_digest", "src", "digest"),)

    id: str = Field(
        primary_key=True, max_length=128
    )  # the backhaul message id: "<gateway>-<incarnation>-<n>"
    frame_id: int | None = Field(
        default=None, sa_column=Column(Integer, ForeignKey("frame.id", ondelete="SET NULL"), index=True)
    )  # the frame row it is (None: dropped before storing, or a stranger's frame deleted since)
    gateway: str = Field(max_length=64, index=True)
    src: int
    digest: str = Field(max_length=64)  # SHA-256 of the frame's bytes (hex)
    snr_in: float | None = None
    at: float  # when the gateway heard it (its clock)
    received_at: float = Field(default_factory=now)  # when the center stored it
    kept: bool = False  # this copy's receive statistics are the frame row's (the best SNR heard)
    # the frame carried a packet heard for the first time whose tag or MAC verified: only such copies
    # score their gateway (``server.routing``); a gateway's claims of what it heard are no evidence
    verified: bool = Field(default=False, sa_column_kwargs={"server_default": "0"})
