"""Three schema functions, imported directly, for :mod:`accelcal.tasks.validate` only.

The by-name resolver that stood here is gone (issue 24): every other caller imports
from ``accelcal.schemas.*`` itself, and tests substitute a function with
``monkeypatch.setattr`` on the schema module.  ``tasks/validate.py`` is being changed
on another branch; when it imports these from ``accelcal.schemas.suites`` /
``accelcal.schemas.datadocs`` directly, this file goes.
"""
from __future__ import annotations

from ..schemas.datadocs import write_drop_index
from ..schemas.suites import docs_folder_name, validate_runs

__all__ = ["docs_folder_name", "validate_runs", "write_drop_index"]
