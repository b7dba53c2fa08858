"""The warehouse's views, one registry: ``views.sql`` (fleet, recalibration history, rig
comparison; each view with its ``*_as_of(ts)`` table macro) read the history tables only.

The names are read from the SQL itself (:func:`view_names`, :func:`macro_names`), never
kept by hand.  :func:`apply_views` runs it on a write connection (the warehouse does so
whenever it applies its schema; ``accelcal.warehouse.ensure_views`` for a file).
``drift.sql`` (recalibration forecasts) is applied by ``accelcal due`` on first use.
"""
from __future__ import annotations

import re
from importlib import resources

#: The SQL files of views applied with the schema, in order.
VIEW_FILES = ("views.sql",)


def views_sql() -> str:
    """The SQL of every registered view file, in order."""
    root = resources.files("accelcal.warehouse")
    return "\n".join(root.joinpath(f).read_text() for f in VIEW_FILES)


def view_names() -> list[str]:
    """The views the registered SQL creates."""
    return re.findall(r"CREATE OR REPLACE VIEW (\w+)", views_sql())


def macro_names() -> list[str]:
    """The table macros (``*_as_of``) the registered SQL creates."""
    return re.findall(r"CREATE OR REPLACE MACRO (\w+)", views_sql())


def apply_views(con) -> None:
    """Create or replace the registered views on a write connection that has the schema."""
    con.execute(views_sql())
