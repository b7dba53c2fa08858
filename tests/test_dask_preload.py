"""The Dask worker preload (accelcal.ops.dask_preload): warms a standing worker, writes
nothing, and never stops a worker from starting."""
import logging

from accelcal.ops import dask_preload


def test_warm_validates_demo_runs_and_writes_nothing(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    seconds = dask_preload.warm()
    assert seconds > 0
    assert list(tmp_path.iterdir()) == []


def test_a_failing_warm_up_is_logged_not_raised(monkeypatch, caplog):
    def broken():
        raise OSError("demo data missing")
    monkeypatch.setattr(dask_preload, "warm", broken)
    with caplog.at_level(logging.WARNING, logger=dask_preload.__name__):
        dask_preload.dask_setup(None)
    assert "warm-up failed (OSError: demo data missing)" in caplog.text
