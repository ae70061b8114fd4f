"""`tacit replay`'s progress bar: the replayed time and the packets stored so far."""

from __future__ import annotations

import asyncio
import io

from launch.replay import wait_with_progress


def test_progress_bar_shows_time_and_packets() -> None:
    out = io.StringIO()
    count = iter(range(100))
    asyncio.run(wait_with_progress(1.2, lambda: next(count), file=out, disable=False, step=0.2))
    text = out.getvalue()
    assert "replay: 100%" in text and "1/1 s" in text and "packets stored" in text
