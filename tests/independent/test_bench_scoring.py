"""The independent diagnosis benchmark's scoring (scripts/bench_diagnosis_independent.py): which answers count."""

from __future__ import annotations

import json
from pathlib import Path
from types import ModuleType

import margcal_independent_generator as gen  # loaded once by tests/conftest.py
import numpy as np
import pytest
from conftest import load_script

from ros_margcal.diagnosis.baseline_noise import shaped_truth
from ros_margcal.model.calibration import Calibration


@pytest.fixture(scope="module")
def bench() -> ModuleType:
    """The script, loaded as when it runs (``conftest.load_script``)."""
    return load_script("bench_diagnosis_independent")


def test_the_shape_is_the_one_the_diagnosis_tolerates(bench: ModuleType) -> None:
    """``true_shape`` measures what ``shaped_truth`` caps: a W whose shape is below the tolerance passes unchanged,
    one above it is scaled to exactly the tolerance."""
    w = np.array([[1.1, 0.03, -0.02], [0.03, 0.95, 0.04], [-0.02, 0.04, 1.0]])
    size = bench.true_shape(w)
    assert size == pytest.approx(np.sqrt(0.03**2 / (1.1 * 0.95) + 0.02**2 / 1.1 + 0.04**2 / 0.95), rel=1e-12)
    cal = Calibration(np.zeros(3), w, norm=1.0, model="sym")
    diag = cal.replace(matrix=np.diag(np.diag(w)), model="diag")
    np.testing.assert_allclose(shaped_truth(diag, cal, 2 * size).matrix, w, rtol=1e-12)
    assert bench.true_shape(shaped_truth(diag, cal, 0.5 * size).matrix) == pytest.approx(0.5 * size, rel=1e-9)


def test_accepted_answers_follow_the_generated_shape_not_the_diagnosis(bench: ModuleType) -> None:
    """A shape effect within the tolerance also accepts ``none``; a clean sensor beyond it also accepts
    ``ellipsoid_shape``; without a tolerance, and for every other effect, only the label counts."""
    assert bench.accepted("ellipsoid_shape", 0.04, 0.05) == ["ellipsoid_shape", "none"]
    assert bench.accepted("ellipsoid_shape", 0.06, 0.05) == ["ellipsoid_shape"]
    assert bench.accepted("none", 0.06, 0.05) == ["none", "ellipsoid_shape"]
    assert bench.accepted("none", 0.04, 0.05) == ["none"]
    assert bench.accepted("ellipsoid_shape", 0.04, 0.0) == ["ellipsoid_shape"]
    assert bench.accepted("nonlinearity", 0.2, 0.05) == ["nonlinearity"]


def test_a_soft_iron_case_can_cancel_the_sensors_own_shape(bench: ModuleType) -> None:
    """Held-out seed 102 on the band: the added soft iron (0.06) leaves a total shape of about 0.01, below the
    sensor's own 0.042 and the 0.05 tolerance: by the tolerance's definition there is no gap to name."""
    rec = gen.generate("mag", "band", 2.0, 50.0, 102, effect="soft_iron", magnitude=0.06)
    base = gen.generate("mag", "band", 2.0, 50.0, 102, effect="none")
    assert bench.true_shape(rec["truth"]["W_sym"]) < 0.02 < bench.true_shape(base["truth"]["W_sym"]) < 0.05


def test_a_saved_run_is_rescored_at_another_tolerance(bench: ModuleType, tmp_path: Path) -> None:
    """``--rescore`` recomputes the accepted answers from the saved shape (or the regenerated one for a run that
    predates it) without diagnosing again; a missing run is a clear exit, not a traceback."""
    rows = [{"part": "held", "effect": "soft_iron", "magnitude": 0.06, "motion": "band", "seed": 102,
             "truth": "ellipsoid_shape", "cause": "none", "true_shape": 0.010},
            {"part": "held", "effect": "soft_iron", "magnitude": 0.06, "motion": "band", "seed": 102,
             "truth": "ellipsoid_shape", "cause": "none"}]
    log = tmp_path / "rows.jsonl"
    log.write_text("\n".join(json.dumps(r) for r in rows) + "\n")
    at_tol = bench.rescore(log, 0.05)
    assert [r["accepted"] for r in at_tol] == [["ellipsoid_shape", "none"]] * 2
    assert at_tol[1]["true_shape"] == pytest.approx(0.010, abs=0.002)
    assert [r["accepted"] for r in bench.rescore(log, 0.0)] == [["ellipsoid_shape"]] * 2
    with pytest.raises(SystemExit, match="no saved run"):
        bench.rescore(tmp_path / "missing.jsonl", 0.05)
