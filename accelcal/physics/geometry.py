"""The geometry of a run, parsed once from its metadata into a typed object.

Every piece of code that needs to know which instrument axis points where (the forward
model, the estimators, the diagnosis, the certificate) reads one of these objects instead
of re-parsing ``mount_plane`` / ``cos_axis`` strings:

* :class:`CentrifugeMount` for ``centrifuge`` and ``sine_centrifuge`` runs,
* :class:`TumbleHead` for ``tumble`` runs,
* :class:`TiltTable` for ``tilt_rotation`` runs.

:func:`geometry_of` builds (and caches) the object of a run.  Axes are indices into
(IA, PA, OA) = (0, 1, 2); signs are +1/-1 (drop-format.md, "Axes and angles").
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from functools import lru_cache

from .axes import AXES, parse_plane, parse_signed_axis, plane_handedness


@dataclass(frozen=True)
class CentrifugeMount:
    """A centrifuge mount (drop-format.md, ``test: centrifuge`` / ``sine_centrifuge``).

    Attributes
    ----------
    e1, e2 : int
        First and second plane axes (indices into IA, PA, OA).
    vertical, vertical_sign : int
        The third axis and +1 when it points up, -1 when down.
    handedness : int
        h = +1 when e1 x e2 points up, -1 when down.
    phi_rad : float
        Nominal mount angle phi [rad]: the direction towards the spindle makes angle phi
        with e1, measured towards e2.
    arm_radius_m : float
        Nominal spindle-to-turning-centre distance R [m].
    rotation_sign : int
        s = +1 for a ``ccw`` table, -1 for ``cw``.
    sine : bool
        True for a ``sine_centrifuge`` run.
    """
    e1: int
    e2: int
    vertical: int
    vertical_sign: int
    handedness: int
    phi_rad: float
    arm_radius_m: float
    rotation_sign: int
    sine: bool = False

    @property
    def phi_deg(self) -> float:
        return math.degrees(self.phi_rad) % 360.0

    @property
    def plane(self) -> str:
        return f"{AXES[self.e1]}-{AXES[self.e2]}"

    @property
    def mount_key(self) -> tuple[str, float]:
        """(plane, phi mod 180 deg): the two polarities of one mount share it."""
        return self.plane, round(self.phi_deg % 180.0, 6)

    @property
    def polarity(self) -> int:
        """+1 for phi in [0, 180) deg, -1 for [180, 360)."""
        return 1 if self.phi_deg < 180.0 - 1e-9 else -1

    @property
    def radial_axis(self) -> tuple[int, int] | None:
        """(axis, sign) of the instrument axis that points towards the spindle, when one does
        (phi a multiple of 90 deg); None otherwise."""
        k = round(self.phi_deg / 90.0)
        if abs(self.phi_deg - 90.0 * k) > 1e-9:
            return None
        return {0: (self.e1, 1), 1: (self.e2, 1), 2: (self.e1, -1), 3: (self.e2, -1), 4: (self.e1, 1)}[k]

    @property
    def ia_polarity(self) -> int | None:
        """+1 when IA points towards the spindle, -1 away, None when IA is not radial."""
        ra = self.radial_axis
        return ra[1] if ra is not None and ra[0] == 0 else None

    @property
    def label(self) -> str:
        return f"{self.plane} {self.phi_deg:g}"


@dataclass(frozen=True)
class TumbleHead:
    """A dividing head in the gravity field (drop-format.md, ``test: tumble``; paper 003).

    Attributes
    ----------
    head_axis : int
        Instrument axis along the (horizontal) head axis.
    cos_axis, cos_sign, sin_axis, sin_sign : int
        The signed axes that point up at head angles 0 and 90 deg.
    """
    head_axis: int
    cos_axis: int
    cos_sign: int
    sin_axis: int
    sin_sign: int

    @property
    def label(self) -> str:
        return (f"head {AXES[self.head_axis]} cos {'+' if self.cos_sign > 0 else '-'}{AXES[self.cos_axis]}"
                f" sin {'+' if self.sin_sign > 0 else '-'}{AXES[self.sin_axis]}")

    @property
    def ia_phase_deg(self) -> float | None:
        """Head angle at which IA points up; None when IA lies on the head axis."""
        if self.cos_axis == 0:
            return 0.0 if self.cos_sign > 0 else 180.0
        if self.sin_axis == 0:
            return 90.0 if self.sin_sign > 0 else 270.0
        return None

    @property
    def other_axis(self) -> int | None:
        """The turning axis that is not IA (None when IA is on the head axis)."""
        if self.ia_phase_deg is None:
            return None
        return self.sin_axis if self.cos_axis == 0 else self.cos_axis


@dataclass(frozen=True)
class TiltTable:
    """A tilted rotary table (drop-format.md, ``test: tilt_rotation``; paper 001).

    Attributes
    ----------
    gamma_rad : float
        Tilt gamma of the table plane [rad].
    sin_axis, sin_sign, cos_axis, cos_sign, normal_axis, normal_sign : int
        The signed axes sensing g sin(gamma) sin(theta), g sin(gamma) cos(theta) and
        g cos(gamma).
    positions : int or None
        Number n of equally spaced table angles.
    """
    gamma_rad: float
    sin_axis: int
    sin_sign: int
    cos_axis: int
    cos_sign: int
    normal_axis: int
    normal_sign: int
    positions: int | None = None

    @property
    def label(self) -> str:
        return f"tilt {math.degrees(self.gamma_rad):g} deg"


Geometry = CentrifugeMount | TumbleHead | TiltTable

_KEYS = {
    "centrifuge": ("mount_plane", "vertical_axis", "mount_angle_deg", "arm_radius_m", "rotation_sense"),
    "sine_centrifuge": ("mount_plane", "vertical_axis", "mount_angle_deg", "arm_radius_m", "rotation_sense"),
    "tumble": ("head_axis", "cos_axis", "sin_axis"),
    "tilt_rotation": ("tilt_deg", "sin_axis", "cos_axis", "normal_axis", "positions"),
}


def geometry_of(meta: Mapping) -> Geometry:
    """The typed geometry of a run from its (typed or raw) metadata.

    Parameters
    ----------
    meta : mapping
        Run metadata: ``test`` and its geometry keys (drop-format.md): mount_plane,
        vertical_axis, mount_angle_deg [deg], arm_radius_m [m], rotation_sense (centrifuges);
        head_axis, cos_axis, sin_axis (tumble); tilt_deg [deg], sin_axis, cos_axis,
        normal_axis, positions (tilt_rotation).

    Returns
    -------
    CentrifugeMount, TumbleHead or TiltTable
        Cached per distinct geometry.

    Raises
    ------
    ValueError (AxisError)
        For axis names, planes or senses the drop format does not allow.
    """
    test = str(meta["test"])
    keys = _KEYS.get(test)
    if keys is None:
        raise ValueError(f"unknown test kind {test!r}")
    return _build(test, tuple(str(meta.get(k, "")) for k in keys))


def rotation_sign(meta: Mapping) -> int:
    """Sign of the table rate about the vertical.

    Parameters
    ----------
    meta : mapping
        Run metadata with ``rotation_sense`` ('ccw' or 'cw'; default and empty: 'ccw').

    Returns
    -------
    int
        s = +1 for a ccw table, -1 for cw (drop-format.md).
    """
    sense = str(meta.get("rotation_sense", "")).strip().lower() or "ccw"
    if sense not in ("ccw", "cw"):
        raise ValueError(f"rotation_sense {sense!r} is not ccw or cw")
    return 1 if sense == "ccw" else -1


@lru_cache(maxsize=4096)
def _build(test: str, vals: tuple[str, ...]) -> Geometry:
    if test in ("centrifuge", "sine_centrifuge"):
        plane, vertical, phi, radius, sense = vals
        e1, e2 = parse_plane(plane)
        v, vs = parse_signed_axis(vertical)
        h = plane_handedness(plane, vertical)
        return CentrifugeMount(e1, e2, v, vs, h, math.radians(float(phi)), float(radius),
                               rotation_sign({"rotation_sense": sense}), test == "sine_centrifuge")
    if test == "tumble":
        head, cos_axis, sin_axis = vals
        c, cs = parse_signed_axis(cos_axis)
        s, ss = parse_signed_axis(sin_axis)
        hd, _ = parse_signed_axis(head)
        return TumbleHead(hd, c, cs, s, ss)
    tilt, sin_axis, cos_axis, normal_axis, positions = vals
    si, ss = parse_signed_axis(sin_axis)
    ci, cs = parse_signed_axis(cos_axis)
    ni, ns = parse_signed_axis(normal_axis)
    n = int(float(positions)) if positions not in ("", "None") else None
    return TiltTable(math.radians(float(tilt)), si, ss, ci, cs, ni, ns, n)
