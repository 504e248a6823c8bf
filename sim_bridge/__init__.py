"""A PX4-like kinematic SITL stub over MAVLink (pymavlink), one vehicle per mission vehicle."""
