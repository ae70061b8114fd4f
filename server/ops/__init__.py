"""Operations of a center: the Prometheus metrics, the retention of relayed frames, backup and restore of
its database (docs/backhaul.md)."""
