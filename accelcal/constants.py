"""Physical constants and display conventions shared by every part of accelcal.

Sources: drop-format.md (earth rate), effects.md (T_ref, display g).
"""
from __future__ import annotations

#: Earth rotation rate, rad/s (drop-format.md, "Omega_e = 7.292115e-5 rad/s").
OMEGA_EARTH = 7.292115e-5
#: Standard gravity, m/s^2. Display only (effects.md); physics uses the run's g_local_m_s2.
G_STANDARD = 9.80665
#: Reference temperature of the temperature model, degC (effects.md).
T_REF_C = 20.0
#: M2 tidal period, s (effects.md, tilt_tide).
M2_PERIOD_S = 44712.0
#: Fixture mount-angle tolerance, rad (1 arc-minute): the half-width of the type-B term for a
#: mount angle the design cannot determine (paper 000 eq 8).  A lab with a better fixture
#: sets its own; it is stored with every result.
MOUNT_ANGLE_TOLERANCE_RAD = 2.908882086657216e-04

# Display units: factor that turns an SI value into the display unit.
MICRO_G = 1e-6 * G_STANDARD          # 1 ug in m/s^2
UG_PER_G2 = 1e-6 / G_STANDARD        # 1 ug/g^2 in s^2/m
UG_PER_G3 = 1e-6 / G_STANDARD ** 2   # 1 ug/g^3 in s^4/m^2
