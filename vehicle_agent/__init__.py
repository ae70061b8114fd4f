"""The vehicle agent: a Raspberry Pi service between ArduSub (MAVLink) and the vehicle's Micro-Modem."""
