"""The shore half of the protocol: ingest of what the vehicles send, and the link engine."""
