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


def test_a_scheduler_only_imports(monkeypatch):
    """On the scheduler the preload imports what unpickling accelcal's tasks needs and
    does not validate anything (that is the workers' warm-up)."""
    from distributed import Scheduler

    def no_warm():
        raise AssertionError("a scheduler must not run the worker warm-up")
    monkeypatch.setattr(dask_preload, "warm", no_warm)
    called = []
    monkeypatch.setattr(dask_preload, "warm_scheduler",
                        lambda: called.append(1) or 0.0)
    dask_preload.dask_setup(Scheduler.__new__(Scheduler))
    assert called == [1]


def test_warm_scheduler_imports_the_task_modules():
    assert dask_preload.warm_scheduler() >= 0
    import sys
    assert "prefect.task_engine" in sys.modules and "accelcal.tasks.validate" in sys.modules
