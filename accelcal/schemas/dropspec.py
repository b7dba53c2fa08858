"""The vocabulary of the drop format ``accelcal-drop/1`` (shared/spec/drop-format.md) that
the run-file parser (:mod:`accelcal.schemas.dropformat`), its row parser
(:mod:`accelcal.schemas.runbody`) and the suites share: the metadata keys, the columns of
each test, the number forms, the stream sizes, and the refusal (:class:`DropFormatError`,
:class:`Refusal`, :func:`cap_detail`).
"""
from __future__ import annotations

import re
from dataclasses import dataclass

from ..effects import TESTS

FORMAT = "accelcal-drop/1"

#: Keys every run has (drop-format.md, "Metadata keys every run has").
COMMON_KEYS: tuple[str, ...] = (
    "format", "run_id", "test", "unit_serial", "unit_model", "campaign", "rig_id",
    "started_at", "site_latitude_deg", "g_local_m_s2", "output_unit", "sample_period_s",
)
_CENTRIFUGE_GEOMETRY = ("arm_radius_m", "rotation_sense", "mount_plane", "mount_angle_deg",
                        "vertical_axis")
#: Keys per test kind (drop-format.md, the ``test:`` sections).
TEST_KEYS: dict[str, tuple[str, ...]] = {
    "tumble": ("head_axis", "cos_axis", "sin_axis"),
    "centrifuge": _CENTRIFUGE_GEOMETRY + ("reading_window_s",),
    "tilt_rotation": ("tilt_deg", "sin_axis", "cos_axis", "normal_axis", "positions"),
    "sine_centrifuge": _CENTRIFUGE_GEOMETRY + ("rate_amplitude_rad_s", "rate_frequency_hz"),
}
#: Required keys per test kind: common + per test.
REQUIRED_KEYS: dict[str, tuple[str, ...]] = {t: COMMON_KEYS + TEST_KEYS[t] for t in TESTS}
#: Optional everywhere.
OPTIONAL_KEYS: tuple[str, ...] = ("operator", "notes", "daq_id", "ambient_temp_c")
#: Keys typed as float in ``RunFile.meta`` (``positions`` is int); all others are str.
FLOAT_KEYS = frozenset({
    "site_latitude_deg", "g_local_m_s2", "sample_period_s", "arm_radius_m", "mount_angle_deg",
    "reading_window_s", "tilt_deg", "rate_amplitude_rad_s", "rate_frequency_hz", "ambient_temp_c",
})
INT_KEYS = frozenset({"positions"})
OUTPUT_UNITS = ("mA", "V", "count", "m/s2")
ROTATION_SENSES = ("ccw", "cw")

#: Columns per test kind, in the spec's order (files may order them differently).
COLUMNS: dict[str, tuple[str, ...]] = {
    "tumble": ("time_s", "position", "angle_deg", "output", "temp_c"),
    "centrifuge": ("time_s", "step", "table_rate_rad_s", "table_angle_deg", "output", "temp_c"),
    "tilt_rotation": ("time_s", "temp_set_c", "temp_c", "rotation_deg", "output"),
    "sine_centrifuge": ("time_s", "table_rate_rad_s", "table_angle_deg", "output"),
}
#: Columns read as int64 (all others float64).
INT_COLUMNS = frozenset({"step", "position"})
#: Columns whose cells may be empty (-> NaN): ``temp_c`` (case temperature, may be
#: missing) and the centrifuge's ``table_angle_deg`` (empty while turning).
NULLABLE_COLUMNS: dict[str, frozenset[str]] = {
    "tumble": frozenset({"temp_c"}),
    "centrifuge": frozenset({"table_angle_deg", "temp_c"}),
    "tilt_rotation": frozenset({"temp_c"}),
    "sine_centrifuge": frozenset(),
}

_META_LINE = re.compile(r"^#\s*([A-Za-z_][A-Za-z0-9_]*)\s*:(.*)$")
_NUMBER = re.compile(r"^\s*[+-]?(?:(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?|nan|inf|infinity)\s*$",
                     re.IGNORECASE | re.ASCII)
_INTEGER = re.compile(r"^\s*[+-]?\d+\s*$", re.ASCII)


#: Longest refusal detail kept (characters); longer ones are cut with "…".
DETAIL_MAX = 300


def cap_detail(text) -> str:
    text = str(text)
    return text if len(text) <= DETAIL_MAX else text[:DETAIL_MAX - 1] + "…"


class DropFormatError(ValueError):
    """A run file that breaks the drop format (drop-format.md, "What the pipeline must refuse").

    Attributes ``path``, ``line`` (1-based, or None), ``rule`` (short kebab id), ``detail``.
    """

    def __init__(self, path, line: int | None, rule: str, detail: str):
        self.path = str(path)
        self.line = None if line is None else int(line)
        self.rule = rule
        self.detail = cap_detail(detail)
        super().__init__(self.__str__())

    def __str__(self) -> str:
        where = self.path if self.line is None else f"{self.path}:{self.line}"
        return f"{where}: {self.rule}: {self.detail}" if self.detail else f"{where}: {self.rule}"

    def __reduce__(self):  # picklable across process/task boundaries
        return (type(self), (self.path, self.line, self.rule, self.detail))

    def as_refusal(self) -> Refusal:
        return Refusal(self.path, self.line, self.rule, self.detail)


def check_test(path, line: int | None, test) -> str:
    """``test`` when it is one of the spec's test kinds; else :class:`DropFormatError`
    ``unknown-test`` (the one place this rule is checked: the parser, and the suites'
    dispatch of a run made without it)."""
    if test not in TESTS:
        raise DropFormatError(path, line, "unknown-test",
                              f"test {test!r} is not one of {', '.join(TESTS)}")
    return test


@dataclass(frozen=True)
class Refusal:
    """Why a file (or one of its lines) is refused; same text form as DropFormatError."""

    path: str
    line: int | None
    rule: str
    detail: str

    def __post_init__(self):
        object.__setattr__(self, "detail", cap_detail(self.detail))

    def __str__(self) -> str:
        where = self.path if self.line is None else f"{self.path}:{self.line}"
        return f"{where}: {self.rule}: {self.detail}"


#: Bytes read at a time, and (about) the bytes of rows parsed at a time.
BLOCK_BYTES = 1 << 20
CHUNK_BYTES = 4 << 20
#: Files up to this size are read into memory once (hash, then parse from the bytes);
#: bigger ones are hashed in one pass and parsed as a stream in a second, straight into
#: their Parquet file (tables.RunParquetStream: no column of theirs is held).
SMALL_FILE = 4 << 20
#: Longest line a run file may have.  The spec's lines are short (a key, a header of a few
#: names, a row of a few numbers); a longer one is refused (``line-too-long``) without
#: ever being held whole in memory.
LINE_MAX = 1 << 16
