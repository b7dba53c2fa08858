"""Fleet / recalibration-history SQL views (accelcal/warehouse/views.sql).

``apply_views(con)`` creates or replaces the views on an open *write*
connection (after schema.sql).  ``ensure_views(path)`` does it for a warehouse
file, taking the writer lock.  ``query_view`` reads a view read-only.
"""
from __future__ import annotations

from importlib import resources
from pathlib import Path
from typing import Any

VIEWS = ("result_dates", "coefficient_versions", "calibration", "unit_history", "coefficient_changes",
         "fleet_latest", "fleet_stats", "fleet_outliers", "rig_comparison", "rig_pairs")
MACROS = ("calibration_as_of", "unit_history_as_of", "coefficient_changes_as_of", "fleet_latest_as_of",
          "fleet_stats_as_of", "fleet_outliers_as_of", "rig_comparison_as_of")


def views_sql() -> str:
    return resources.files("accelcal.warehouse").joinpath("views.sql").read_text()


def apply_views(con) -> None:
    """Create/replace the ops views on a DuckDB connection that has schema.sql applied."""
    con.execute(views_sql())


def has_views(con) -> bool:
    n = con.execute("SELECT count(*) FROM duckdb_views() WHERE view_name = 'unit_history' "
                    "AND NOT internal").fetchall()[0][0]
    return bool(n)


def ensure_views(warehouse: str | Path, lock_timeout: float = 60.0) -> None:
    """Apply views.sql to a warehouse file (write connection, holds the lock)."""
    from ..warehouse.db import Warehouse
    wh = Warehouse(warehouse, lock_timeout=lock_timeout)
    with wh.connect() as con:
        apply_views(con)


def query_view(warehouse: str | Path, sql: str, params: list | None = None) -> list[dict[str, Any]]:
    """Run a read-only query against a warehouse (views must have been applied)."""
    from ..warehouse.db import Warehouse
    return Warehouse(Path(warehouse).expanduser().resolve()).query(sql, params)
