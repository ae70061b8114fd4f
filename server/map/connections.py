"""The 3D map's websocket server (viser, on ``websockets``) and connections a browser gives up.

``websockets`` logs every failed opening handshake as an error with its traceback, three chained
exceptions long. A browser gives up connections before sending their request as a matter of course: a
tab closed while the page loads, a connection it opened ahead of need and did not use. Such a failure
(the peer closed or reset the connection before its request was read) is one line at INFO here;
any other handshake failure stays an error with its traceback.
"""

from __future__ import annotations

import logging

GIVEN_UP = "a browser closed a connection to the 3D map before sending its request (a tab closed early)"


class GivenUpConnections(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        if record.msg == "opening handshake failed" and record.exc_info and _given_up(record.exc_info[1]):
            record.levelno, record.levelname = logging.INFO, logging.getLevelName(logging.INFO)
            record.msg, record.args, record.exc_info, record.exc_text = GIVEN_UP, (), None, None
        return True


def _given_up(exc: BaseException | None) -> bool:
    """The connection ended (EOF, reset) before the request was read: somewhere in the chain of causes."""
    while exc is not None:
        if isinstance(exc, EOFError | ConnectionError):
            return True
        exc = exc.__cause__ or exc.__context__
    return False


FILTER = GivenUpConnections()


def quiet_given_up_connections() -> None:
    """Install the filter on the websocket server's logger (once: the same filter is not added twice)."""
    logging.getLogger("websockets.server").addFilter(FILTER)
