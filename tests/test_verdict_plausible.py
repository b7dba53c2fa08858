"""An estimate far beyond the catalogue's plausible size is not a verdict (effects.md gives
each effect its largest plausible size): a cross_coupling of 1e-3 s2/m would be a broken
instrument, and on a gap no catalogue effect made it is the evidence that the gap is
something else."""
from __future__ import annotations

from accelcal.diagnosis.core import IMPLAUSIBLE, _Diagnosis
from accelcal.effects import EFFECTS


def test_an_estimate_beyond_ten_times_the_plausible_size_is_no_verdict_and_says_why():
    lim = EFFECTS["cross_coupling"].plausible
    far = {"effect": "cross_coupling", "estimate": -1.2e-3, "note": ""}
    assert -1.2e-3 < -IMPLAUSIBLE * lim          # the sine case: about 1,000 x
    assert _Diagnosis.implausible(far)
    assert "not a verdict" in far["note"] and "plausible size" in far["note"]
    near = {"effect": "cross_coupling", "estimate": 3 * lim, "note": "linear estimate"}
    assert not _Diagnosis.implausible(near) and near["note"] == "linear estimate"
    assert not _Diagnosis.implausible({"effect": "cross_coupling", "estimate": None, "note": ""})
