"""What SYS_STATUS says about the sensors while PX4 boots. Pure.

Measured on PX4 SIH (../shared/px4-sih/characterisation/px4_sih_1x.log): the first SYS_STATUS
reports no sensor present at all; the IMU, magnetometer and barometer appear ~2.2 s (sim) after
boot, without GPS and with the pre-arm check failing ("Preflight Fail: heading estimate not
stable"); at ~4.2 s GPS is present and the pre-arm check passes, and only then does PX4 arm.
The arming rule itself lives with the arming code (``vehicle.modes``); it reads :data:`HEALTH_SETTLED_S`.
"""

from __future__ import annotations

from pymavlink.dialects.v20 import common as mavlink

SENSORS_PRESENT_S = 2.2  # sim s after boot: IMU, mag, baro present
HEALTH_SETTLED_S = 4.2  # sim s after boot: GPS present, estimator settled, pre-arm checks pass

INERTIAL = (mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO | mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL
            | mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG | mavlink.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE)
SENSORS_OK = INERTIAL | mavlink.MAV_SYS_STATUS_SENSOR_GPS
PREARM_CHECK = mavlink.MAV_SYS_STATUS_PREARM_CHECK


def sensor_bits(sim_t_s: float, prearm_ok: bool) -> tuple[int, int, int]:
    """(present, enabled, health) of SYS_STATUS at ``sim_t_s`` after boot.

    ``prearm_ok``: the vehicle's own pre-arm verdict (battery and so on) once the boot is over.
    """
    if sim_t_s < SENSORS_PRESENT_S:
        return 0, 0, INERTIAL  # nothing present yet (PX4 reports health bits regardless)
    if sim_t_s < HEALTH_SETTLED_S:
        present = INERTIAL | PREARM_CHECK
        return present, present, INERTIAL
    present = SENSORS_OK | PREARM_CHECK
    return present, present, SENSORS_OK | (PREARM_CHECK if prearm_ok else 0)
