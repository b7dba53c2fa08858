"""GUM 7.2.6 rounding: U to two significant digits, the value to the same decimal place."""
import pytest

from accelcal.effects import display_coefficient
from accelcal.rounding import format_sig, round_gum


@pytest.mark.parametrize("value,U,v,u", [
    (3.8441, 0.0312, "3.844", "0.031"),
    (-119.98690608, 0.029989865, "-119.987", "0.030"),     # K1T: trailing zero kept
    (0.7147750123, 0.50e-6, "0.71477501", "0.00000050"),   # radius, U 0.50 um: 0.01 um shown
    (1.2999999312, 1.43e-7, "1.29999993", "0.00000014"),   # K1 with U 0.11 ppm
    (41.08831, 0.0469, "41.088", "0.047"),
    (12345.6, 996.0, "12300", "1000"),                       # 996 -> 1000 (2 digits: 1.0e3)
    (0.2925, 0.0996, "0.29", "0.10"),                        # 0.0996 -> 0.10, value to 0.01
    (5.0e-5, 0.0028, "0.0001", "0.0028"),
    (-1e-9, 0.3, "0.00", "0.30"),                            # no "-0.00"
    (2.5, 0.15, "2.50", "0.15"),
])
def test_round_gum(value, U, v, u):
    r = round_gum(value, U)
    assert (r.value, r.uncertainty) == (v, u)


def test_round_gum_without_uncertainty():
    assert round_gum(3.14159265, None) == ("3.14159", "—", None)
    assert round_gum(None, 0.1).value == "—"
    assert round_gum(float("nan"), 0.1).value == "—"
    assert round_gum(1.0, 0.0).uncertainty == "—"


def test_format_sig():
    assert format_sig(0.0299899) == "0.030"
    assert format_sig(0.114) == "0.11"
    assert format_sig(None) == "—"


def test_display_units_follow_the_rule():
    # K1 in mA/g with U in ppm: the value carries as many digits as the absolute U needs
    v, U, unit = display_coefficient("K1", 0.13256310, 7.25e-9, "mA/(m/s2)")
    assert unit == "mA/g" and U == "0.11 ppm" and v == "1.29999992"   # U = 1.4e-7 mA/g
    v, U, unit = display_coefficient("K1T", -1.1998690608e-4, 1.4994932768e-8, "1/degC")
    assert (v, U, unit) == ("-119.987", "0.030", "ppm/°C")


def test_k1_display_unit_keeps_an_output_unit_with_a_slash():
    """K1 of a run whose output is already an acceleration (m/s2): its display unit is the
    output unit per g, not the first token of the SI unit."""
    from accelcal.effects import si_unit, to_display
    assert to_display("K1", 1.0, 1e-6, si_unit("K1", "m/s2"))[2] == "m/s2/g"
    assert to_display("K1", 0.13, 1e-9, si_unit("K1", "mA"))[2] == "mA/g"
