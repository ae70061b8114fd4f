"""The backhaul between the shore's gateways (one per shore modem) and the center, over NATS JetStream.

The gateway's modules (``subjects``, ``outbox``, ``gateway``) import the standard library, the core and
nats-py only: a gateway on a buoy installs ``tacit[gateway]``, no web stack. The center's modules
(``center``, ``relay``, ``repository``, ``models``) join the backhaul to the shore's storage and ingest;
``leases`` and ``live`` let several center processes share that work.
See docs/backhaul.md.
"""
