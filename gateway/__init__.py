"""The gateway wing: the shore's one MAC (``gateway.mac``: slots, attempts, ACKs, polls, pings) and its
queue (``gateway.queue``: what goes in this slot, for whom), run by every shore modem's process.

Imports the core (``tacit``), the standard library and nats-py only: no web stack, no database.
"""
