"""A TCP relay between a split demo's gateway and its broker: ``python -m launch.relay --listen PORT --to
HOST:PORT``. Its process stands for that gateway's backhaul alone: SIGSTOP it and the link goes silent
(no reset, a radio link lost), SIGCONT and it comes back; SIGKILL it and the link is reset. It ends when
the demo that started it does (``TACIT_PARENT_PID``)."""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import os

from tacit.cli import PARENT, end_with_parent


async def _pipe(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
    with contextlib.suppress(ConnectionError, OSError):
        while data := await reader.read(65536):
            writer.write(data)
            await writer.drain()
    writer.close()


async def _serve(port: int, host: str, to: int) -> None:
    async def relay(reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        try:
            upstream = await asyncio.open_connection(host, to)
        except OSError:
            writer.close()
            return
        await asyncio.gather(_pipe(reader, upstream[1]), _pipe(upstream[0], writer))

    server = await asyncio.start_server(relay, "127.0.0.1", port)
    async with server:
        await server.serve_forever()


def main() -> None:
    parser = argparse.ArgumentParser(prog="python -m launch.relay", description=__doc__)
    parser.add_argument("--listen", type=int, required=True, help="the port on 127.0.0.1 to listen on")
    parser.add_argument("--to", required=True, help="HOST:PORT to relay to")
    args = parser.parse_args()
    end_with_parent(os.environ.pop(PARENT, None))
    host, port = args.to.rsplit(":", 1)
    asyncio.run(_serve(args.listen, host, int(port)))


if __name__ == "__main__":
    main()
