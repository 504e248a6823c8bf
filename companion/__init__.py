"""A*-BDWA offboard companion: cooperative obstacle avoidance for a pair of UAVs over MAVLink."""

__version__ = "0.1.0"
