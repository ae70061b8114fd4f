"""Which center process does what when several run behind one database: leases in a JetStream KV bucket
named as the center's durables (``tacit-center``: two centers on one broker, each with its ``--durable``,
do not share theirs), whose entries' age limit is the lease.

* ``member.<instance>``: each live center process, written at every renewal with its database (a
  process whose database is not its group's is refused: ``tacit center``); a dead one's expires.
* ``partition.<p>``: the process that consumes frames partition ``p`` (``subjects.partition``) and
  decodes its vehicles.
* ``coordinator``: the process that runs the singletons (the routing, the TDMA schedules, the SYNC
  budgets, the gateways' events, retention).

A lease is created only if absent and renewed with the revision this process last wrote (an update that
expects it), so two processes never hold one at once; one a process failed to renew for a whole lease
(the broker away) is taken for lost. Partition ``p`` is wanted by the ``p % n``-th of the ``n`` live
members in name order: spread evenly, and every process computes the same spread. A process lets go of
a partition another member wants (the caller stops consuming it and saves its vehicles' states first),
and takes one it wants when it is free; a killed process's leases expire and the others take its
partitions at their next renewal.

Why leases rather than the broker's own work distribution: nats-server 2.9 has neither consumers with
several filter subjects nor pinned clients, so one durable consumer per partition, each read by one
process at a time, is how the vehicles are shared; the bucket's ``max_age`` is the lease (2.9 has no
per-message TTL).
"""

from __future__ import annotations

import json
import logging
import time

from nats.errors import Error as NatsError
from nats.js import JetStreamContext
from nats.js.errors import BadRequestError, KeyNotFoundError, KeyWrongLastSequenceError, NotFoundError
from nats.js.kv import KeyValue

from server.backhaul import subjects

log = logging.getLogger("tacit.backhaul.leases")

COORDINATOR = "coordinator"


def partition_key(part: int) -> str:
    return f"partition.{part}"


class Leases:
    def __init__(
        self, js: JetStreamContext, bucket: str, instance: str, ttl: float, database: str = ""
    ) -> None:
        """``database``: which database this process stores into (``center.database_identity``)."""
        self.js = js
        self.database = database
        self.bucket = bucket
        self.instance = subjects.gateway_name(instance)  # one subject token, as a gateway's name
        self.ttl = ttl
        self.kv: KeyValue | None = None
        self.held: dict[str, tuple[int, float]] = {}  # key: the revision written, when (monotonic)

    async def open(self) -> None:
        """The bucket, created by the first process (with its ``ttl``) and bound by the others."""
        try:
            self.kv = await self.js.create_key_value(bucket=self.bucket, ttl=self.ttl, history=1)
        except BadRequestError:  # made by a process with another lease: that one holds for all
            self.kv = await self.js.key_value(self.bucket)
            info = await self.js.stream_info(f"KV_{self.bucket}")
            self.ttl = info.config.max_age or self.ttl
            log.warning("center %s: the leases bucket's lease is %.1f s", self.instance, self.ttl)

    async def bind(self) -> bool:
        """The bucket if it exists (made by a running or earlier process), without making it."""
        try:
            self.kv = await self.js.key_value(self.bucket)
        except NotFoundError:
            return False
        return True

    def holds(self, key: str) -> bool:
        return key in self.held

    def fresh(self, key: str) -> bool:
        """Held and renewed less than a lease ago: another process cannot have taken it."""
        held = self.held.get(key)
        return held is not None and time.monotonic() - held[1] < self.ttl

    async def members(self) -> list[str]:
        """The live processes' instances in name order."""
        return list(await self.entries())

    async def entries(self) -> dict[str, dict[str, object]]:
        """The live processes' entries (``instance``, ``database``, ``at``) by instance, in name order."""
        kv = self._kv()
        prefix = f"$KV.{self.bucket}.member."
        info = await self.js.stream_info(f"KV_{self.bucket}", subjects_filter=f"{prefix}>")
        found: dict[str, dict[str, object]] = {}
        for subject in sorted(info.state.subjects or {}):
            try:
                entry = await kv.get(subject.removeprefix(f"$KV.{self.bucket}."))
            except KeyNotFoundError:  # a member that left (deleted)
                continue
            try:
                value = json.loads(entry.value or b"")
            except json.JSONDecodeError:
                value = {}
            found[subject.removeprefix(prefix)] = value if isinstance(value, dict) else {}
        return found

    @staticmethod
    def wanted(members: list[str], instance: str) -> set[int]:
        """The partitions ``instance`` should hold among ``members``."""
        if instance not in members:
            return set()
        return {p for p in range(subjects.PARTITIONS) if members[p % len(members)] == instance}

    async def renew(self) -> None:
        """This process announced as a member, and every lease held renewed; one lost (another process
        holds it, or not renewed for a lease) is held no more. Its own loop, apart from the work of
        taking and letting go, which may take longer than a lease (a replay)."""
        kv = self._kv()
        try:
            await kv.put(f"member.{self.instance}", self._value())
        except (NatsError, TimeoutError) as exc:  # the leases below still expire after a lease
            log.warning("center %s: not announced: %s", self.instance, exc)
        for key, (revision, at) in list(self.held.items()):
            try:
                renewed = await kv.update(key, self._value(), last=revision)
            except KeyWrongLastSequenceError:
                self._lost(key)
                continue
            except (NatsError, TimeoutError) as exc:
                log.warning("center %s: lease %s not renewed: %s", self.instance, key, exc)
                if time.monotonic() - at > self.ttl:
                    self._lost(key)
                continue
            if key in self.held:  # not released meanwhile
                self.held[key] = (renewed, time.monotonic())

    def _lost(self, key: str) -> None:
        if self.held.pop(key, None) is not None:
            log.warning("center %s: lost its lease on %s", self.instance, key)

    async def take(self, key: str) -> bool:
        """Take ``key``'s lease if nobody holds it; whether this process holds it now."""
        if key in self.held:
            return True
        try:
            self.held[key] = (await self._kv().create(key, self._value()), time.monotonic())
        except KeyWrongLastSequenceError:  # held by another process
            return False
        log.info("center %s: took %s", self.instance, key)
        return True

    async def release(self, key: str) -> None:
        """Let go of ``key`` (deleted, so that another process takes it at once)."""
        held = self.held.pop(key, None)
        if held is None:
            return
        try:
            await self._kv().delete(key, last=held[0])
        except (NatsError, TimeoutError, KeyWrongLastSequenceError) as exc:  # it expires all the same
            log.warning("center %s: lease %s not released: %s", self.instance, key, exc)
        log.info("center %s: released %s", self.instance, key)

    async def leave(self) -> None:
        """This process is stopping: its member entry deleted (its leases are released by the caller)."""
        try:
            await self._kv().delete(f"member.{self.instance}")
        except (NatsError, TimeoutError) as exc:
            log.warning("center %s: not deleted from the members: %s", self.instance, exc)

    def _value(self) -> bytes:
        return json.dumps({"instance": self.instance, "database": self.database, "at": time.time()}).encode()

    def _kv(self) -> KeyValue:
        assert self.kv is not None, "open() first"
        return self.kv
