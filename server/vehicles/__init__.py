"""Vehicles: registration, keys and their staged rotation, limits."""
