"""A scripted Micro-Modem on a real pty, for driver tests: it answers host sentences by rules.

The driver opens ``path``, a symlink to the pty's slave side (as socat's ``link=`` gives), so the
modem can "vanish" (close the pty, remove the link) and "come back" on a new pty at the same path.
"""

from __future__ import annotations

import os
import select
import threading
import time
import tty
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

from tacit import nmea

S = TypeVar("S", bound=nmea.Sentence)
Rule = Callable[["ScriptedModem", nmea.Sentence | nmea.Raw], list[str]]


def default_rule(modem: ScriptedModem, sentence: nmea.Sentence | nmea.Raw) -> list[str]:
    """Echo every host command as the real modem does; answer CFQ with CFG."""
    if isinstance(sentence, nmea.ConfigQuery):
        return [nmea.Config(sentence.name, modem.config.get(sentence.name, "0")).line(nmea.MODEM)]
    if isinstance(sentence, nmea.Config):
        modem.config[sentence.name] = sentence.value
        return [sentence.line(nmea.MODEM)]
    if isinstance(sentence, nmea.TxData):
        return [nmea.TxDataEcho(sentence.src, sentence.dest, sentence.ack, len(sentence.data)).line()]
    if isinstance(sentence, nmea.Sentence):
        return [sentence.line(nmea.MODEM)]
    return []


class ScriptedModem:
    def __init__(self, path: Path, rule: Rule = default_rule) -> None:
        self.path = path
        self.rule = rule
        self.config: dict[str, str] = {"SRC": "0"}
        self.received: list[nmea.Sentence | nmea.Raw] = []
        self.silent = False
        self._master: int | None = None
        self._slave: int | None = None
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()
        self.appear()

    def appear(self) -> None:
        master, slave = os.openpty()
        tty.setraw(master)
        self._master, self._slave = master, slave
        if self.path.is_symlink() or self.path.exists():
            self.path.unlink()
        self.path.symlink_to(os.ttyname(slave))
        self._thread = threading.Thread(target=self._run, args=(master,), daemon=True)
        self._thread.start()

    def vanish(self) -> None:
        master, slave = self._master, self._slave
        self._master = self._slave = None
        self.path.unlink(missing_ok=True)
        for fd in (master, slave):
            if fd is not None:
                os.close(fd)
        if self._thread:
            self._thread.join(timeout=2)

    def send(self, line: str | bytes) -> None:
        with self._lock:
            if self._master is not None:
                os.write(self._master, line.encode("ascii") if isinstance(line, str) else line)

    def wait_for(self, kind: type[S], timeout: float = 5.0, count: int = 1) -> list[S]:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            found = [s for s in self.received if isinstance(s, kind)]
            if len(found) >= count:
                return found
            time.sleep(0.01)
        raise AssertionError(f"modem never received {count} x {kind.__name__}: {self.received}")

    def _run(self, master: int) -> None:
        buffer = b""
        while self._master == master:
            try:
                ready, _, _ = select.select([master], [], [], 0.05)
                if not ready:
                    continue
                chunk = os.read(master, 1024)
            except OSError:
                return
            buffer += chunk
            *lines, buffer = buffer.split(b"\n")
            for line in lines:
                try:
                    sentence = nmea.parse(line)
                except nmea.NmeaError:
                    continue
                self.received.append(sentence)
                if not self.silent:
                    for reply in self.rule(self, sentence):
                        self.send(reply)

    def close(self) -> None:
        self.vanish()
