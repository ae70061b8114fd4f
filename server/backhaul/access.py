"""Who may do what on the broker: each role's user and NATS permissions, the credentials a client
connects with, and ``tacit broker-config``, which writes a nats-server configuration for a list of
gateways.

One user per role: ``center``, and ``gateway-<name>`` per gateway. A gateway may publish only its own
frames and events (its command outcomes among them), create and read only its own command consumer
(``gateway-<name>``, filtered on its own command subject) and its own schedule consumer
(``schedule-<name>``, filtered on its own schedule subject; it deletes it at start to begin again at the
last schedule kept) and its own SYNC budget consumer (``syncs-<name>``, likewise, on its own vehicles'
budgets: no gateway reads the pre-signed SYNCs of a vehicle it does not serve), and receive replies only on its own inbox prefix (``_INBOX.gateway.<name>``), so it
can neither pass frames off as another's nor see another's commands or schedule, even in a reply. It
cannot create, change or delete a stream: the center does. A client without credentials is refused by
the broker.

Standard library only: the gateway imports it.
"""

from __future__ import annotations

import argparse
import json
import os
import secrets
import ssl
import stat
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from server.backhaul import subjects

CENTER = "center"
GATEWAY_CONSUMER = "gateway-{name}"  # the durable each gateway reads its commands through
SCHEDULE_CONSUMER = "schedule-{name}"  # the durable each gateway reads its schedule through
SYNCS_CONSUMER = "syncs-{name}"  # the durable each gateway reads its vehicles' SYNC budgets through


class CredentialsError(ValueError):
    """A credentials file that cannot be used (unreadable, too open, missing a field)."""


def gateway_user(name: str) -> str:
    return f"gateway-{subjects.gateway_name(name)}"


def inbox_prefix(user: str) -> str:
    """The user's own reply subjects: ``_INBOX.center`` or ``_INBOX.gateway.<name>``."""
    return "_INBOX." + user.replace("gateway-", "gateway.", 1)


@dataclass(frozen=True)
class BrokerAuth:
    """How a client connects: a user and password (none: a broker without accounts, development only),
    and the CA that signs the broker's certificate when the URL is ``tls://``."""

    user: str | None = None
    password: str | None = None
    ca_file: str | None = None

    @property
    def restricted(self) -> bool:
        """A user of a broker with permissions: streams are the center's to create."""
        return self.user is not None and self.user != CENTER

    @classmethod
    def load(cls, credentials: str | Path | None, ca_file: str | None = None) -> BrokerAuth:
        """From a credentials file (TOML: ``user``, ``password``) readable by its owner only."""
        if not credentials:
            return cls(ca_file=ca_file or None)
        path = Path(credentials)
        try:
            if path.stat().st_mode & (stat.S_IRWXG | stat.S_IRWXO):
                raise CredentialsError(f"{path}: must not be readable by group or others (chmod 600)")
            body = tomllib.loads(path.read_text())
            return cls(str(body["user"]), str(body["password"]), ca_file or None)
        except (OSError, KeyError, tomllib.TOMLDecodeError) as exc:
            raise CredentialsError(f"{path}: not a credentials file ({exc})") from None

    def options(self) -> dict[str, Any]:
        """Keyword arguments for ``nats.connect``."""
        options: dict[str, Any] = {}
        if self.user is not None:
            options.update(user=self.user, password=self.password, inbox_prefix=inbox_prefix(self.user))
        if self.ca_file:
            options["tls"] = ssl.create_default_context(cafile=self.ca_file)
        return options


def gateway_permissions(name: str) -> dict[str, Any]:
    """What gateway ``name`` may publish and subscribe to (JetStream's API is a set of subjects)."""
    consumer = GATEWAY_CONSUMER.format(name=subjects.gateway_name(name))
    stream = subjects.COMMANDS_STREAM
    schedule, plan = SCHEDULE_CONSUMER.format(name=name), subjects.SCHEDULE_STREAM
    syncs, budget = SYNCS_CONSUMER.format(name=name), subjects.SYNCS_STREAM
    return {
        "publish": {
            "allow": [
                subjects.frames(name),
                subjects.events(name),
                f"$JS.API.CONSUMER.INFO.{stream}.{consumer}",
                f"$JS.API.CONSUMER.CREATE.{stream}.{consumer}.{subjects.commands(name)}",
                f"$JS.API.CONSUMER.MSG.NEXT.{stream}.{consumer}",
                f"$JS.ACK.{stream}.{consumer}.>",
                f"$JS.API.CONSUMER.INFO.{plan}.{schedule}",
                f"$JS.API.CONSUMER.DELETE.{plan}.{schedule}",
                f"$JS.API.CONSUMER.CREATE.{plan}.{schedule}.{subjects.schedule(name)}",
                f"$JS.API.CONSUMER.MSG.NEXT.{plan}.{schedule}",
                f"$JS.ACK.{plan}.{schedule}.>",
                f"$JS.API.CONSUMER.INFO.{budget}.{syncs}",
                f"$JS.API.CONSUMER.DELETE.{budget}.{syncs}",
                f"$JS.API.CONSUMER.CREATE.{budget}.{syncs}.{subjects.syncs(name)}",
                f"$JS.API.CONSUMER.MSG.NEXT.{budget}.{syncs}",
                f"$JS.ACK.{budget}.{syncs}.>",
            ]
        },
        "subscribe": {"allow": [inbox_prefix(gateway_user(name)) + ".>"]},
    }


def center_permissions() -> dict[str, Any]:
    """The center: every stream and consumer (its partitions' durables and ``<durable>-events``), the
    commands, schedules and SYNC budgets down, its processes' leases (a KV bucket named as its durables)
    and live events; it publishes no frame or event."""
    down = [subjects.commands(">"), subjects.schedule(">"), subjects.syncs(">")]
    return {
        "publish": {"allow": [*down, subjects.live(">"), "$KV.>", "$JS.API.>", "$JS.ACK.>"]},
        "subscribe": {
            "allow": [
                subjects.frames(">"),
                subjects.events(">"),
                subjects.live(">"),
                inbox_prefix(CENTER) + ".>",
            ]
        },
    }


def server_config(
    passwords: dict[str, str],
    listen: str = "127.0.0.1:4222",
    store: str = "/var/lib/nats",
    tls: tuple[str, str] | None = None,
) -> str:
    """A nats-server configuration: JetStream on file storage, one user per role (``passwords`` by user:
    ``center`` and ``gateway-<name>``), TLS with ``(cert, key)`` when given. JSON, which nats-server
    reads, so that every subject is quoted (``$JS`` would otherwise be a variable)."""
    users = [
        {
            "user": user,
            "password": password,
            "permissions": center_permissions()
            if user == CENTER
            else gateway_permissions(user.removeprefix("gateway-")),
        }
        for user, password in sorted(passwords.items())
    ]
    config: dict[str, Any] = {
        "listen": listen,
        "jetstream": {"store_dir": store},
        "authorization": {"users": users},
    }
    if tls is not None:
        config["tls"] = {"cert_file": tls[0], "key_file": tls[1]}
    header = "# nats-server configuration written by `tacit broker-config` (docs/backhaul.md)\n"
    return header + json.dumps(config, indent=2) + "\n"


def credentials_text(user: str, password: str) -> str:
    return f"# tacit: this role's broker credentials (--nats-credentials)\nuser = {json.dumps(user)}\npassword = {json.dumps(password)}\n"


def _write_private(path: Path, text: str) -> None:
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(text)
    path.chmod(0o600)


def _password(folder: Path, user: str) -> str:
    """The user's password from an earlier run (adding a gateway rotates nobody's), else a new one."""
    existing = folder / f"{user}.toml"
    if existing.exists():
        return BrokerAuth.load(existing).password or secrets.token_urlsafe(24)
    return secrets.token_urlsafe(24)


def write(
    folder: Path,
    gateways: list[str],
    listen: str,
    store: str,
    tls: tuple[str, str] | None = None,
) -> list[Path]:
    """The broker's configuration and one credentials file per role in ``folder``; the paths."""
    folder.mkdir(parents=True, exist_ok=True)
    users = [CENTER, *sorted({gateway_user(g) for g in gateways})]
    passwords = {user: _password(folder, user) for user in users}
    paths = [folder / "nats-server.conf", *(folder / f"{user}.toml" for user in users)]
    _write_private(paths[0], server_config(passwords, listen, store, tls))
    for user, path in zip(users, paths[1:], strict=True):
        _write_private(path, credentials_text(user, passwords[user]))
    return paths


def add_arguments_for_client(parser: argparse.ArgumentParser, env: Mapping[str, str]) -> None:
    """A client's options (the gateway's and the center's), defaulting to ``TACIT_NATS_*`` in ``env``."""
    parser.add_argument(
        "--nats-credentials",
        default=env.get("TACIT_NATS_CREDENTIALS"),
        help="this role's credentials file from `tacit broker-config` (default TACIT_NATS_CREDENTIALS; "
        "none: a broker without accounts, for development)",
    )
    parser.add_argument(
        "--nats-ca",
        default=env.get("TACIT_NATS_CA"),
        help="the CA of the broker's certificate, for a tls:// URL (default TACIT_NATS_CA)",
    )


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Write a nats-server configuration with one user per role (the center, each gateway) and their "
        "permissions, and each role's credentials file (mode 600). Run it again with one more --gateway "
        "to add a gateway: the others keep their passwords. Then: nats-server -c OUT/nats-server.conf"
    )
    parser.add_argument(
        "--gateway", action="append", default=[], required=True, help="a gateway's name (repeat for each)"
    )
    parser.add_argument("--out", type=Path, default=Path("broker"), help="the folder (default %(default)s)")
    parser.add_argument(
        "--listen", default="127.0.0.1:4222", help="the broker's address (default %(default)s)"
    )
    parser.add_argument(
        "--store", default="/var/lib/nats", help="JetStream's storage folder (default %(default)s)"
    )
    parser.add_argument("--tls-cert", help="the broker's certificate (PEM): TLS on every connection")
    parser.add_argument("--tls-key", help="its private key (PEM), with --tls-cert")


def run(args: argparse.Namespace) -> int:
    if bool(args.tls_cert) != bool(args.tls_key):
        raise SystemExit("tacit broker-config: --tls-cert and --tls-key go together")
    try:
        names = [subjects.gateway_name(g) for g in args.gateway]
    except ValueError as exc:
        raise SystemExit(f"tacit broker-config: {exc}") from None
    tls = (args.tls_cert, args.tls_key) if args.tls_cert else None
    for path in write(args.out, names, args.listen, args.store, tls):
        print(path)
    return 0
