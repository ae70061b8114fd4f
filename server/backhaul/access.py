"""Who may do what on the broker: each role's account, user and NATS permissions, the credentials a
client connects with, and ``tacit broker-config``, which writes a nats-server configuration for a
deployment's gateways beside other deployments'.

One account per role, each with one user of that name: ``center``, and ``gateway-<name>`` per gateway
(``<deployment>.center`` and ``<deployment>.gateway-<name>`` for a named deployment,
``subjects.Deployment``). Accounts, not user permissions: nats-server answers a JetStream request, and
delivers what a consumer pulls, to whatever reply subject the request names, with its own rights; only
an account boundary stops that. The center's account holds JetStream (the streams, the consumers, the
leases bucket) and exports to each gateway's account only that gateway's subjects, as services: its
frames and events (a publish's acknowledgement comes back as the service's reply), the information
about, the pull of and the acks on its own three consumers (commands, schedule, SYNC budgets), and the
last schedule kept for it. A reply into a gateway's account stays there, whatever subject the request
named. The center makes the gateways' consumers (``broker.ensure_gateway_consumers``); a gateway makes
none, it binds to them. Within its account a gateway's user may publish only what it imports and
receive only its own replies, so a misdirected request is refused loudly. A client without
credentials is refused by the broker.

Standard library only: the gateway imports it.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import secrets
import ssl
import stat
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path
from typing import Any

from server.backhaul import subjects
from server.backhaul.subjects import UNNAMED, Deployment

log = logging.getLogger("tacit.backhaul.access")

CENTER = "center"
GATEWAY_API = "tacit.center.API"  # the center's JetStream API as a gateway's account imports it
CONFIG = "nats-server.conf"


class BrokerMode(StrEnum):
    """How a center reaches its broker: with its account's credentials, or without (``--insecure``)."""

    ACCOUNTS = "accounts"
    INSECURE = "insecure"

    @classmethod
    def of(cls, credentials: str | None, insecure: bool) -> BrokerMode | None:
        """None: no broker (``tacit serve``)."""
        return cls.ACCOUNTS if credentials else cls.INSECURE if insecure else None


class CredentialsError(ValueError):
    """Credentials that cannot be used (unreadable, too open, missing a field, another deployment's), or
    none where they are needed."""


def gateway_role(name: str) -> str:
    return f"gateway-{subjects.gateway_name(name)}"


def user_name(deployment: Deployment, role: str) -> str:
    """A role's user, and its account: ``center``, ``gateway-ship``; ``lab.center`` in deployment lab."""
    return f"{deployment.name}.{role}" if deployment.name else role


def gateway_user(name: str, deployment: Deployment = UNNAMED) -> str:
    return user_name(deployment, gateway_role(name))


def inbox_prefix(role: str) -> str:
    """The role's own reply subjects: ``_INBOX.center`` or ``_INBOX.gateway.<name>``."""
    return "_INBOX." + role.replace("gateway-", "gateway.", 1)


@dataclass(frozen=True)
class GatewayConsumer:
    """One of a gateway's consumers, which the center makes: on ``stream``, named ``name``, of ``subject``
    (names as on the deployment's broker); ``last``: it begins at the last message of each subject (the
    schedule, the SYNC budgets), else at the first (the commands)."""

    stream: str
    name: str
    subject: str
    last: bool


def gateway_consumers(name: str, deployment: Deployment = UNNAMED) -> tuple[GatewayConsumer, ...]:
    """Gateway ``name``'s commands, schedule and SYNC budget consumers."""
    d, name = deployment, subjects.gateway_name(name)
    return (
        GatewayConsumer(d.named(subjects.COMMANDS_STREAM), d.named(f"gateway-{name}"),
                        d.subject(subjects.commands(name)), last=False),
        GatewayConsumer(d.named(subjects.SCHEDULE_STREAM), d.named(f"schedule-{name}"),
                        d.subject(subjects.schedule(name)), last=True),
        GatewayConsumer(d.named(subjects.SYNCS_STREAM), d.named(f"syncs-{name}"),
                        d.subject(subjects.syncs(name)), last=True),
    )  # fmt: skip


@dataclass(frozen=True)
class BrokerAuth:
    """How a client connects: a user and password (none: a broker without accounts, development only),
    and the CA that signs the broker's certificate when the URL is ``tls://``."""

    user: str | None = None
    password: str | None = None
    ca_file: str | None = None

    @property
    def role(self) -> str | None:
        """``center`` or ``gateway-<name>``; None without credentials."""
        return None if self.user is None else self.user.rsplit(".", 1)[-1]

    @property
    def deployment(self) -> Deployment:
        """The deployment the user belongs to (none without credentials)."""
        return Deployment(self.user.rsplit(".", 1)[0] if self.user and "." in self.user else "")

    @property
    def restricted(self) -> bool:
        """A gateway's account: JetStream is the center's, reached through its imports."""
        return self.role is not None and self.role != CENTER

    @property
    def api_prefix(self) -> str:
        """Where this client's JetStream API is: the center's own, or a gateway's imports of it."""
        return GATEWAY_API if self.restricted else "$JS.API"

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
            role = self.role or CENTER
            options.update(user=self.user, password=self.password, inbox_prefix=inbox_prefix(role))
        if self.ca_file:
            options["tls"] = ssl.create_default_context(cafile=self.ca_file)
        return options


def client_auth(
    who: str, credentials: str | None, ca_file: str | None, insecure: bool, deployment: Deployment
) -> BrokerAuth:
    """A client's credentials, checked: none only when told ``insecure`` (said in a warning), and of its
    deployment; raises CredentialsError with the one line to print."""
    if insecure and credentials:
        raise CredentialsError("--insecure and --nats-credentials: one or the other")
    if not credentials:
        if not insecure:
            raise CredentialsError(
                "no broker credentials (--nats-credentials, a file `tacit broker-config` writes); "
                "--insecure runs on a broker without accounts, for development only"
            )
        log.warning("%s: INSECURE: no broker credentials, on a broker without accounts (--insecure)", who)
        return BrokerAuth(ca_file=ca_file or None)
    auth = BrokerAuth.load(credentials, ca_file)
    if auth.deployment != deployment:
        raise CredentialsError(
            f"{credentials}: credentials of deployment {auth.deployment.name!r}, "
            f"this is deployment {deployment.name!r} (--deployment, TACIT_DEPLOYMENT)"
        )
    return auth


def _service(subject: str, account: str, stream: bool = False) -> dict[str, Any]:
    export: dict[str, Any] = {"service": subject, "accounts": [account]}
    if stream:
        export["response_type"] = "stream"  # a pull: many messages answer one request
    return export


def _imported(subject: str) -> str:
    """The subject a gateway's account knows an export of the center's by: its JetStream API under
    ``GATEWAY_API`` (its own ``$JS.API`` is the server's, which has no JetStream for it)."""
    return subject.replace("$JS.API", GATEWAY_API, 1) if subject.startswith("$JS.API.") else subject


def gateway_exports(name: str, deployment: Deployment = UNNAMED) -> list[dict[str, Any]]:
    """What the center's account exports to gateway ``name``'s, and nothing else: its frames and events
    (services: the stream's acknowledgement is the reply), its consumers' information, pull and acks, and
    the last schedule kept for it."""
    d, account = deployment, gateway_user(name, deployment)
    exports = [
        _service(d.subject(subjects.frames(name)), account),
        _service(d.subject(subjects.events(name)), account),
    ]
    for consumer in gateway_consumers(name, d):
        exports += [
            _service(f"$JS.API.CONSUMER.INFO.{consumer.stream}.{consumer.name}", account),
            _service(f"$JS.API.CONSUMER.MSG.NEXT.{consumer.stream}.{consumer.name}", account, stream=True),
            _service(f"$JS.ACK.{consumer.stream}.{consumer.name}.>", account),
        ]
    schedule = d.named(subjects.SCHEDULE_STREAM)
    exports.append(_service(f"$JS.API.DIRECT.GET.{schedule}.{d.subject(subjects.schedule(name))}", account))
    return exports


def gateway_requests(name: str, deployment: Deployment = UNNAMED) -> list[str]:
    """The subjects gateway ``name`` may publish to in its account: its imports of the center's exports."""
    return [_imported(export["service"]) for export in gateway_exports(name, deployment)]


def gateway_account(name: str, password: str, deployment: Deployment = UNNAMED) -> dict[str, Any]:
    """Gateway ``name``'s account: its user, who may publish only what it imports and receive only its
    own replies; no JetStream of its own."""
    center = user_name(deployment, CENTER)
    local = gateway_requests(name, deployment)
    imports = [
        {"service": {"account": center, "subject": export["service"]}, "to": _imported(export["service"])}
        for export in gateway_exports(name, deployment)
    ]
    permissions = {
        "publish": {"allow": local},
        "subscribe": {"allow": [inbox_prefix(gateway_role(name)) + ".>"]},
    }
    user = {"user": gateway_user(name, deployment), "password": password, "permissions": permissions}
    return {"users": [user], "imports": imports}


def center_permissions(deployment: Deployment = UNNAMED) -> dict[str, Any]:
    """The center in its account: every stream and consumer (its partitions' durables and
    ``<durable>-events``, the gateways'), the commands, schedules and SYNC budgets down, its processes'
    leases (a KV bucket) and live events; it publishes no frame or event."""
    d = deployment
    down = [
        d.subject(subjects.commands(">")),
        d.subject(subjects.schedule(">")),
        d.subject(subjects.syncs(">")),
    ]
    return {
        "publish": {"allow": [*down, d.subject(subjects.live(">")), "$KV.>", "$JS.API.>", "$JS.ACK.>"]},
        "subscribe": {
            "allow": [
                d.subject(subjects.frames(">")),
                d.subject(subjects.events(">")),
                d.subject(subjects.live(">")),
                inbox_prefix(CENTER) + ".>",
            ]
        },
    }


def deployment_accounts(
    deployment: Deployment, passwords: dict[str, str], gateways: list[str]
) -> dict[str, dict[str, Any]]:
    """A deployment's accounts by name: its center's (JetStream, the exports) and each gateway's."""
    center = user_name(deployment, CENTER)
    exports = [export for name in gateways for export in gateway_exports(name, deployment)]
    accounts: dict[str, dict[str, Any]] = {
        center: {
            "jetstream": "enabled",
            "users": [
                {"user": center, "password": passwords[center], "permissions": center_permissions(deployment)}
            ],
            "exports": exports,
        }  # fmt: skip
    }
    for name in gateways:
        accounts[gateway_user(name, deployment)] = gateway_account(
            name, passwords[gateway_user(name, deployment)], deployment
        )
    return accounts


def _of(account: str, deployment: Deployment) -> bool:
    """Whether an account of a configuration is ``deployment``'s."""
    return account.rsplit(".", 1)[0] == deployment.name if "." in account else not deployment.name


def server_config(
    accounts: dict[str, dict[str, Any]],
    listen: str = "127.0.0.1:4222",
    store: str = "/var/lib/nats",
    tls: tuple[str, str] | None = None,
) -> str:
    """A nats-server configuration: JetStream on file storage, ``accounts`` (every deployment's), TLS with
    ``(cert, key)`` when given. JSON, which nats-server reads, so that every subject is quoted (``$JS``
    would otherwise be a variable)."""
    config: dict[str, Any] = {"listen": listen, "jetstream": {"store_dir": store}, "accounts": accounts}
    if tls is not None:
        config["tls"] = {"cert_file": tls[0], "key_file": tls[1]}
    header = "# nats-server configuration written by `tacit broker-config` (docs/backhaul.md)\n"
    return header + json.dumps(config, indent=2) + "\n"


def read_config(path: Path) -> dict[str, Any]:
    """A configuration ``server_config`` wrote (empty if there is none); raises ValueError for another."""
    if not path.exists():
        return {}
    text = "\n".join(line for line in path.read_text().splitlines() if not line.lstrip().startswith("#"))
    try:
        config = json.loads(text)
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path} is not a configuration `tacit broker-config` wrote ({exc})") from None
    if not isinstance(config, dict):
        raise ValueError(f"{path} is not a configuration `tacit broker-config` wrote")
    return config


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
    listen: str | None = None,
    store: str | None = None,
    tls: tuple[str, str] | None = None,
    deployment: Deployment = UNNAMED,
) -> list[Path]:
    """The broker's configuration in ``folder`` with ``deployment``'s accounts (the other deployments' it
    holds kept, and its address, store and TLS unless given), and one credentials file per role of the
    deployment; the paths."""
    folder.mkdir(parents=True, exist_ok=True)
    existing = read_config(folder / CONFIG)
    kept = {
        name: account for name, account in existing.get("accounts", {}).items() if not _of(name, deployment)
    }
    names = sorted({subjects.gateway_name(g) for g in gateways})
    users = [user_name(deployment, CENTER), *(gateway_user(g, deployment) for g in names)]
    passwords = {user: _password(folder, user) for user in users}
    if tls is None and "tls" in existing:
        tls = (existing["tls"]["cert_file"], existing["tls"]["key_file"])
    config = server_config(
        {**kept, **deployment_accounts(deployment, passwords, names)},
        listen or existing.get("listen") or "127.0.0.1:4222",
        store or existing.get("jetstream", {}).get("store_dir") or "/var/lib/nats",
        tls,
    )
    paths = [folder / CONFIG, *(folder / f"{user}.toml" for user in users)]
    _write_private(paths[0], config)
    for user, path in zip(users, paths[1:], strict=True):
        _write_private(path, credentials_text(user, passwords[user]))
    return paths


def add_arguments_for_client(parser: argparse.ArgumentParser, env: Mapping[str, str]) -> None:
    """A client's options (the gateway's and the center's), defaulting to ``TACIT_*`` in ``env``."""
    parser.add_argument(
        "--nats-credentials",
        default=env.get("TACIT_NATS_CREDENTIALS"),
        help="this role's credentials file from `tacit broker-config` (default TACIT_NATS_CREDENTIALS)",
    )
    parser.add_argument(
        "--nats-ca",
        default=env.get("TACIT_NATS_CA"),
        help="the CA of the broker's certificate, for a tls:// URL (default TACIT_NATS_CA)",
    )
    parser.add_argument(
        "--insecure",
        action="store_true",
        default=env.get("TACIT_NATS_INSECURE", "").lower() in {"1", "true", "yes"},
        help="run without credentials on a broker without accounts (development only; TACIT_NATS_INSECURE)",
    )
    parser.add_argument(
        "--deployment",
        default=env.get("TACIT_DEPLOYMENT"),
        help="the split shore's name on its broker: it prefixes every subject, stream, consumer and bucket "
        "(default TACIT_DEPLOYMENT, or none)",
    )


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.description = (
        "Write a nats-server configuration with one account per role of a deployment (its center, each "
        "gateway), and each role's credentials file (mode 600). Run it again with one more --gateway to "
        "add a gateway (the others keep their passwords), or with another --deployment to add a deployment "
        "beside the ones the file holds. Then: nats-server -c OUT/nats-server.conf (or --signal reload)"
    )
    parser.add_argument(
        "--gateway", action="append", default=[], required=True, help="a gateway's name (repeat for each)"
    )
    parser.add_argument(
        "--deployment", default="", help="the deployment's name (default: none, the subjects unprefixed)"
    )
    parser.add_argument("--out", type=Path, default=Path("broker"), help="the folder (default %(default)s)")
    parser.add_argument(
        "--listen", default=None, help="the broker's address (default: the file's, else 127.0.0.1:4222)"
    )
    parser.add_argument(
        "--store", default=None, help="JetStream's storage folder (default: the file's, else /var/lib/nats)"
    )
    parser.add_argument("--tls-cert", help="the broker's certificate (PEM): TLS on every connection")
    parser.add_argument("--tls-key", help="its private key (PEM), with --tls-cert")


def run(args: argparse.Namespace) -> int:
    if bool(args.tls_cert) != bool(args.tls_key):
        raise SystemExit("tacit broker-config: --tls-cert and --tls-key go together")
    try:
        names = [subjects.gateway_name(g) for g in args.gateway]
        deployment = Deployment(args.deployment)
        tls = (args.tls_cert, args.tls_key) if args.tls_cert else None
        paths = write(args.out, names, args.listen, args.store, tls, deployment)
    except ValueError as exc:
        raise SystemExit(f"tacit broker-config: {exc}") from None
    for path in paths:
        print(path)
    return 0
