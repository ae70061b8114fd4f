"""Tacit: compressed acoustic communications for underwater vehicles (shared core).

The shared core has no web or database imports, so it runs on the vehicle's Raspberry Pi.
"""

__version__ = "0.1.0"
