"""Simulators: the acoustic channel, Micro-Modems on ptys, and a BlueROV2 speaking MAVLink."""
