"""Missions: recorded on the shore, started and aborted by a control packet."""
