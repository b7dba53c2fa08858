"""Submitted tasks' large arguments are Sealed: Prefect does not walk into them, and they
reach the plain function as they were (accelcal.tasks.Sealed)."""
from __future__ import annotations

import pickle

import pytest

from accelcal.tasks import Sealed, load_and_process_sealed


def test_prefect_does_not_walk_into_a_sealed_argument():
    pytest.importorskip("prefect")
    from prefect.utilities.collections import visit_collection
    seen = []
    inner = [{"run_id": f"r{k}", "sha256": "0" * 64} for k in range(50)]

    def visit(x):
        seen.append(type(x).__name__)
        return x
    visit_collection(Sealed(inner), visit, return_data=False)
    assert seen == ["Sealed"]
    seen.clear()
    visit_collection(inner, visit, return_data=False)     # the same data, unsealed
    assert len(seen) > 50


def test_a_sealed_argument_survives_pickling_and_is_unwrapped(monkeypatch):
    from accelcal.tasks import science
    calls = []
    monkeypatch.setattr(science, "load_and_process",
                        lambda root, campaigns, parameters: calls.append((root, campaigns, parameters)))
    chunks = [[{"run_id": "a"}], [{"run_id": "b"}]]
    sealed = pickle.loads(pickle.dumps(Sealed(chunks)))
    load_and_process_sealed("/wh", sealed, Sealed({"mc": 100}))
    assert calls == [("/wh", chunks, {"mc": 100})]
