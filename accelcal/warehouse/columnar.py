"""Transactions and columnar writes on a DuckDB connection: the helpers every writer of
the warehouse uses (run records, results, the migration).  Many rows go as one Arrow
insert per table, never row by row; ``Checkpoint`` lets the fault tests stop a write at a
named step (``_cp``)."""
from __future__ import annotations

import contextlib
from typing import TYPE_CHECKING, Callable, Iterator

import duckdb

if TYPE_CHECKING:
    import pyarrow as pa

Checkpoint = Callable[[str], None] | None


def _transaction(con) -> contextlib.AbstractContextManager:
    @contextlib.contextmanager
    def tx():
        con.execute("BEGIN TRANSACTION")
        try:
            yield con
        except BaseException:
            try:
                con.execute("ROLLBACK")
            except Exception:
                pass
            raise
        con.execute("COMMIT")
    return tx()


def _column(values: list) -> "pa.Array":
    """An Arrow column of Python values; a column mixing types Arrow cannot unify goes as
    text, which DuckDB casts to the table's type exactly as it casts a bound parameter
    (repr of a float round-trips)."""
    import pyarrow as pa
    try:
        return pa.array(values)
    except (pa.ArrowInvalid, pa.ArrowTypeError):
        return pa.array([None if v is None else str(v) for v in values], type=pa.string())


def _attr_columns(objs: list, names: tuple[str, ...]) -> dict[str, list]:
    """Columns ``name -> [getattr(o, name) for o in objs]``."""
    return {n: [getattr(o, n) for o in objs] for n in names}


def _arrow(columns: dict[str, list]):
    import pyarrow as pa
    return pa.table({k: _column(v) for k, v in columns.items()})


@contextlib.contextmanager
def _registered(con, name: str, table) -> Iterator[None]:
    """``table`` (Arrow) visible to SQL on ``con`` as view ``name`` for the block."""
    con.register(name, table)
    try:
        yield
    finally:
        with contextlib.suppress(duckdb.Error):
            con.unregister(name)


def _insert(con, table: str, columns: dict[str, list | None]) -> None:
    """One columnar INSERT of many rows: ``columns`` maps column -> values (Python
    lists, all of one length); ``None`` instead of a list means now() (the
    transaction's timestamp, as the row-wise inserts used).  DuckDB casts each Arrow
    column to the table's type."""
    data = {k: v for k, v in columns.items() if v is not None}
    sel = ", ".join(f'"{k}"' if v is not None else "now()" for k, v in columns.items())
    with _registered(con, "_insert_rows", _arrow(data)):
        con.execute(f"INSERT INTO {table} ({', '.join(columns)}) "
                    f"SELECT {sel} FROM _insert_rows").fetchall()


def _nextvals(con, sequence: str, n: int) -> list[int]:
    """The next ``n`` values of a sequence, in order (as n row-wise nextval() calls)."""
    return sorted(v for (v,) in con.execute(
        f"SELECT nextval('{sequence}') FROM range(?)", [n]).fetchall())


def _cp(checkpoint: Checkpoint, step: str) -> None:
    if checkpoint is not None:
        checkpoint(step)
