"""Shared fixtures: where the lab's example drops are, and the truth they were made from."""
from __future__ import annotations

import fcntl
import os
import shutil
import sys
from pathlib import Path
from typing import Callable

import pytest

REPO = Path(__file__).resolve().parents[1]

if os.environ.get("PYTEST_XDIST_WORKER"):
    # each test worker (pytest-xdist, pyproject's addopts) its own Prefect home, so two
    # workers' temporary Prefect servers never share one SQLite database; set before any
    # test module imports Prefect, and inherited by every command a test starts
    _home = Path(os.environ.get("PREFECT_HOME") or Path.home() / ".prefect")
    _home = _home / f"pytest-{os.environ['PYTEST_XDIST_WORKER']}"
    _home.mkdir(parents=True, exist_ok=True)
    os.environ["PREFECT_HOME"] = str(_home)
SHARED = Path(os.environ.get("ACCELCAL_SHARED", REPO.parent / "shared"))
EXAMPLES = SHARED / "examples"
#: Why a test that reads the lab's samples is skipped when they are absent (README, "Tests").
NO_SHARED = (f"needs the lab's sample data at {SHARED} (the shared/ folder beside this checkout; "
             "or set ACCELCAL_SHARED)")


#: Marks a test that reads the lab's samples: skipped, with :data:`NO_SHARED`, without them.
needs_shared = pytest.mark.skipif(not EXAMPLES.is_dir(), reason=NO_SHARED)


def require_shared() -> None:
    """Skip the calling test module, with :data:`NO_SHARED` as the reason, when the lab's
    sample drops are not there (call it at module level, before reading them)."""
    if not EXAMPLES.is_dir():
        pytest.skip(NO_SHARED, allow_module_level=True)

#: Truth behind ../shared/examples/drop-2026-11-20 (quoted in issues 2 and 4).
TRUTH_20 = {"K2": 3.94e-7, "Kpp": 4.7e-8, "Kip": 7.1e-7, "Kio": 2.0e-7, "Koo": 3.0e-8, "Koq": 3.0e-8,
            "K3": 2.0e-10, "R+": 0.714775, "R-": 0.705794}


def marked_pids(variable: str, mark: str) -> list[int]:
    """Processes whose environment carries ``variable=mark`` (a test's run and everything
    it started, at any depth: what must not outlive it)."""
    needle = f"\0{variable}={mark}\0".encode()
    out = []
    for d in os.listdir("/proc"):
        try:
            if d.isdigit() and needle in b"\0" + Path(f"/proc/{d}/environ").read_bytes() + b"\0":
                out.append(int(d))
        except OSError:
            pass
    return out


@pytest.fixture(scope="session")
def examples() -> Path:
    if not EXAMPLES.is_dir():
        pytest.skip(NO_SHARED)
    return EXAMPLES


#: The lab's stated rig-input uncertainties of the sample drops' rigs (accelcal.toml, issue 27):
#: with them the budgets are complete and a certificate can be final.
RIG_INPUTS_TOML = """[rigs."LXJ-100"]
g_local_u_m_s2 = 1e-5
[rigs."DH-1"]
g_local_u_m_s2 = 1e-5
[rigs."TT-1"]
g_local_u_m_s2 = 1e-5
tilt_u_deg = 0.001
temperature_u_c = 0.05
[rigs."DC-1"]
g_local_u_m_s2 = 1e-5
"""


#: The sample drops of the shared warehouse (:func:`sample_lab`).
SAMPLE_LAB_DROPS = ("drop-2026-11-20", "drop-2026-11-21", "drop-bad")


def built_once(tmp_path_factory, name: str, build: Callable[[Path], None]) -> Path:
    """A folder ``build`` fills once per test run, shared by every test process
    (pytest-xdist workers): the first to ask builds it, under the run's common temporary
    folder and an exclusive lock, and the others wait for it.  Open what it holds only
    through :func:`copy_lab` (two processes must never write one DuckDB file)."""
    root = tmp_path_factory.getbasetemp()
    if os.environ.get("PYTEST_XDIST_WORKER"):
        root = root.parent                      # the folder all workers' temp folders are in
    d = root / name
    with open(root / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not (d / ".built").exists():
            shutil.rmtree(d, ignore_errors=True)
            d.mkdir()
            build(d)
            (d / ".built").touch()
    return d


@pytest.fixture(scope="session")
def sample_lab(tmp_path_factory, examples) -> Path:
    """One warehouse of the sample drops 2026-11-20, 2026-11-21 and drop-bad (local
    engine, no config), built once per test run (:func:`built_once`); tests use copies of
    it (:func:`copy_lab`)."""
    from accelcal.flows.pipeline import run_pipeline
    from accelcal.warehouse import ensure_views

    def build(d: Path) -> None:
        run_pipeline([str(examples / x) for x in SAMPLE_LAB_DROPS], d / "lab.duckdb", engine="local")
        ensure_views(d / "lab.duckdb")
    return built_once(tmp_path_factory, "sample-lab", build) / "lab.duckdb"


#: The drops of the one-process reference run of the scale-out tests (:func:`reference_lab`).
REFERENCE_DROPS = ("drop-2026-11-20", "drop-bad", "drop-2026-11-21")


@pytest.fixture(scope="session")
def reference_lab(tmp_path_factory, examples) -> Path:
    """The warehouse one process leaves (local engine, no config) from
    :data:`REFERENCE_DROPS` as they lie in the samples folder, built once per test run
    (:func:`built_once`): what the Dask and worker-pool runs of the same drops must equal.
    Its run's summary is beside it (``summary.json``). Read it only."""
    import json

    from accelcal.flows.pipeline import run_pipeline

    def build(d: Path) -> None:
        s = run_pipeline([examples / x for x in REFERENCE_DROPS], d / "lab.duckdb", engine="local")
        (d / "summary.json").write_text(json.dumps(s, default=str))
    return built_once(tmp_path_factory, "reference-lab", build) / "lab.duckdb"


#: The drops of the certificate and DCC warehouse (:func:`certified_lab`): one campaign of
#: each rig kind the certificates show (centrifuge + tumble, thermal, sine).
CERTIFIED_LAB_DROPS = ("drop-2026-11-20", "drop-2026-11-18-thermal", "drop-2026-11-19-sine")


@pytest.fixture(scope="session")
def certified_lab(tmp_path_factory, examples) -> Path:
    """One warehouse of :data:`CERTIFIED_LAB_DROPS` processed with the rigs' stated input
    uncertainties (:data:`RIG_INPUTS_TOML`), built once per test run (:func:`built_once`);
    the certificate and DCC tests copy it and write their own accelcal.toml beside the copy
    (read when a certificate is made)."""
    from accelcal.config import rig_uncertainties
    from accelcal.flows.pipeline import run_pipeline

    def build(d: Path) -> None:
        toml = d / "rigs.toml"
        toml.write_text(RIG_INPUTS_TOML)
        run_pipeline([str(examples / x) for x in CERTIFIED_LAB_DROPS], d / "lab.duckdb", engine="local",
                     parameters={"rig_uncertainty": rig_uncertainties(toml)})
        toml.unlink()
    return built_once(tmp_path_factory, "certified-lab", build) / "lab.duckdb"


def copy_lab(warehouse: Path, into: Path) -> Path:
    """A copy of a warehouse with everything beside it (Parquet, extras, Data Docs), for a
    test that writes; returns the copy's ``lab.duckdb``."""
    shutil.copytree(warehouse.parent, into)
    return into / warehouse.name


def pytest_collection_modifyitems(config, items):
    """Modules holding a slow test first, each keeping its order: the workers take a
    module at a time (``--dist loadfile``), so the long ones start early and the short
    ones fill in at the end."""
    slow = {it.path for it in items if it.get_closest_marker("slow")}
    items.sort(key=lambda it: it.path not in slow)


def pytest_sessionstart(session):
    """accelcal's bytecode, compiled once before the tests start.  The suite starts some
    sixty Python processes that import accelcal (CLI runs, worker pools, Dask workers); an
    editable install has no ``.pyc`` of its own, and where PYTHONDONTWRITEBYTECODE is set
    each of them compiled all of accelcal again (about 0.5 CPU s each).
    Compiling is what Python does itself on the first import; nothing is checked less."""
    if sys.dont_write_bytecode and not os.environ.get("PYTEST_XDIST_WORKER"):
        import compileall
        compileall.compile_dir(REPO / "accelcal", quiet=2)
