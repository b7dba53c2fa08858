"""DuckDB warehouse: schema (schema.sql), the Warehouse (db), its write lock (lock), the
results writer (results), the extras store (extras), lineage, views."""
from .db import RunRecord, Refusal, Warehouse, ensure_views
from .errors import WarehouseBusy, WarehouseError
from .lock import holds_lock, warehouse_lock
from .lineage import code_version, result_id, trace, validator_version, verify_lineage

__all__ = ["RunRecord", "Refusal", "Warehouse", "WarehouseBusy", "WarehouseError", "ensure_views",
           "holds_lock", "warehouse_lock", "code_version", "result_id", "trace", "validator_version",
           "verify_lineage"]
