"""Prometheus' text format as the center writes it: HELP and TYPE before the samples, labels escaped,
integers without a decimal point, NaN for a value the gateway did not send."""

from __future__ import annotations

import math

from server.ops.exposition import Family, render


def test_families_render_in_prometheus_text_format() -> None:
    text = render(
        [
            Family("tacit_gateway_up", "1 while it beats").add(1, gateway="ship").add(0, gateway='b"u\\oy\n'),
            Family("tacit_backhaul_refused_total", "Refused", "counter").add(2.5).add(math.nan, reason="x"),
        ]
    )
    assert text.splitlines() == [
        "# HELP tacit_gateway_up 1 while it beats",
        "# TYPE tacit_gateway_up gauge",
        'tacit_gateway_up{gateway="ship"} 1',
        'tacit_gateway_up{gateway="b\\"u\\\\oy\\n"} 0',
        "# HELP tacit_backhaul_refused_total Refused",
        "# TYPE tacit_backhaul_refused_total counter",
        "tacit_backhaul_refused_total 2.5",
        'tacit_backhaul_refused_total{reason="x"} NaN',
    ]
    assert text.endswith("\n")
