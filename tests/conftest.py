"""Shared fixtures: seeded generators, a known true calibration, and the optional real recordings."""

from __future__ import annotations

import importlib.util
import os
import sys
from collections.abc import Callable
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest
from hypothesis import settings

from ros_margcal.model.calibration import Calibration
from ros_margcal.recordings.recording import Recording
from ros_margcal.ros.environment import use_venv_ament_prefix
from ros_margcal.sim.simulation import magnetometer_stream, random_sensor, tumbling, tumbling_motion

# ROS 2 from the PyPI wheels needs AMENT_PREFIX_PATH (a sourced Jazzy has it); node tests on one machine must
# never hear each other: a domain of this run's own (children inherit it) and discovery on this host only
use_venv_ament_prefix()
os.environ.setdefault("ROS_DOMAIN_ID", str(1 + os.getpid() % 100))
os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")

# property tests seeded like every other generator here: the same examples on every run and machine, so a red CI is
# a change's, not a draw's (HYPOTHESIS_PROFILE=explore draws new ones, to look for more)
settings.register_profile("seeded", derandomize=True, database=None)
settings.register_profile("explore", derandomize=False)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "seeded"))

REAL_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "real"


@pytest.fixture
def rng() -> np.random.Generator:
    """A generator with a fixed seed, fresh for every test."""
    return np.random.default_rng(20261121)


@pytest.fixture
def true_cal() -> Calibration:
    """A magnetometer-like truth: hard-iron offset, unequal gains and cross-axis terms (raw in µT)."""
    w = np.array([[1.08, 0.04, -0.02], [0.04, 0.93, 0.03], [-0.02, 0.03, 1.01]])
    return Calibration(np.array([12.0, -7.5, 30.0]), w, norm=48.0, model="sym", sensor="mag", unit="uT")


@pytest.fixture
def real_data_dir() -> Path:
    """``../shared/data/real`` beside the checkout; the test is skipped when it is absent."""
    if not REAL_DATA.is_dir():
        pytest.skip(f"real recordings not present at {REAL_DATA} (they live outside the package)")
    return REAL_DATA


@pytest.fixture
def real_recording(real_data_dir: Path) -> Callable[[str], Path]:
    """``real_recording(name)``: the path of one real recording; the test is skipped when it is absent."""

    def path(name: str) -> Path:
        p = real_data_dir / name
        if not p.exists():
            pytest.skip(f"{name} not present in {real_data_dir}")
        return p

    return path


def _load_independent() -> ModuleType:
    spec = importlib.util.spec_from_file_location("margcal_independent_generator",
                                                  Path(__file__).with_name("independent") / "generator.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # test modules import it by this name: one loader, one module object
    spec.loader.exec_module(module)
    return module


INDEPENDENT = _load_independent()
"""``tests/independent/generator.py`` (importable as ``margcal_independent_generator`` in tests): recordings
made without any code of the package."""


@pytest.fixture
def independent() -> ModuleType:
    """The independent generator (see ``INDEPENDENT``)."""
    return INDEPENDENT


SCRIPTS = Path(__file__).resolve().parents[1] / "scripts"


def load_script(name: str) -> ModuleType:
    """``scripts/NAME.py`` as a module, loaded with scripts/ importable (as when it runs); the test is skipped when the
    checkout has no scripts/."""
    path = SCRIPTS / f"{name}.py"
    if not path.exists():
        pytest.skip("scripts/ is not in this checkout")
    mp = pytest.MonkeyPatch()
    mp.syspath_prepend(str(SCRIPTS))
    spec = importlib.util.spec_from_file_location(name, path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    mp.undo()
    return module


def tumbling_imu(seconds: float, rate_hz: float, seed: int) -> tuple[Recording, Recording]:
    """``(accelerometer, magnetometer)`` recordings of one tumbling IMU (the package's simulator), seeded."""
    rng = np.random.default_rng(seed)
    motion = tumbling_motion(seconds, rate_hz, rng)
    acc = tumbling(random_sensor(rng, "accel"), seconds, rate_hz, rng, motion=motion)
    mag = magnetometer_stream(random_sensor(rng, "mag"), seconds, rate_hz, rng, motion=motion)
    return acc, mag
