"""The Vehicle port (``port``) and its adapters (``mavsdk_vehicle`` for real MAVLink links)."""
