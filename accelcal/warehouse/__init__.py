"""DuckDB warehouse: schema (schema.sql), transactional idempotent store (db), lineage."""
from .db import (RunRecord, Refusal, Warehouse, WarehouseBusy, WarehouseError, ensure_views,
                 holds_lock, warehouse_lock)
from .lineage import code_version, result_id, trace, validator_version, verify_lineage

__all__ = ["RunRecord", "Refusal", "Warehouse", "WarehouseBusy", "WarehouseError", "ensure_views",
           "holds_lock", "warehouse_lock", "code_version", "result_id", "trace", "validator_version",
           "verify_lineage"]
