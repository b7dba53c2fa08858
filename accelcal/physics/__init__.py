"""Rig physics: axes, the instrument model and the rig kinematics (the one forward model)."""
from .axes import AXES, parse_plane, parse_signed_axis, plane_handedness  # noqa: F401
from .instrument import first_order_lag, indicated_acceleration, output, scale_factor  # noqa: F401
from .rigs import (NOMINAL, centrifuge_specific_force, omega_z, rig_output, specific_force,  # noqa: F401
                   tilt_rotation_specific_force, tumble_specific_force)
