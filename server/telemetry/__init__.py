"""Telemetry: frames and packets as heard, their trust, reconstructed samples, exports."""
