"""The replay timeline's status cadence runs on the stream's own clock: a dropped stamp never moves it.

Before, the cadence ran on each message's stamp: one far-future stamp (dropped as ``bad_stamp``) printed a
status at 1e18 s at every such message, and one jumped stamp (dropped as ``stamp_jump``) printed a status at
the jump and then none for as long as the jump.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from ros_margcal.recordings.csvfile import write_csv
from ros_margcal.recordings.recording import Recording
from ros_margcal.sim import simulation as sim
from ros_margcal.stream.replay import replay

EVERY_S = 5.0


def _statuses(path: Path) -> list[float]:
    out = replay(path, sensor="mag", unit="T", status_every=EVERY_S, progress=False)
    return [e["t"] for e in out["timeline"] if e["kind"] == "status"]


@pytest.fixture(scope="module")
def stream() -> Recording:
    truth = sim.random_sensor(np.random.default_rng(41), "mag")
    return sim.magnetometer_stream(truth, 60.0, 50.0, np.random.default_rng(42), motion="tumble")


@pytest.mark.parametrize("glitch", [1e18, 5000.0])
def test_a_dropped_stamp_neither_prints_a_status_nor_silences_the_timeline(
        stream: Recording, glitch: float, tmp_path: Path) -> None:
    clean = _statuses(write_csv(tmp_path / "clean_mag.csv", stream))
    t = stream.t.copy()
    t[[500, 1500, 2500]] += glitch  # single stamps off the time base: each dropped, the next one back on it
    glitched = _statuses(write_csv(tmp_path / "glitched_mag.csv", dataclasses.replace(stream, t=t)))
    assert max(glitched) <= stream.t[-1]
    assert np.all(np.diff(glitched) <= EVERY_S + 0.1)  # none missing after a glitch
    assert len(glitched) == len(clean)
    assert np.allclose(glitched, clean, atol=0.05)


def test_stamps_that_restart_restart_the_cadence(stream: Recording, tmp_path: Path) -> None:
    t = stream.t.copy()
    half = len(t) // 2
    t[half:] -= t[half] - t[0]  # the second half restamped from the start (a new time base)
    got = _statuses(write_csv(tmp_path / "restart_mag.csv", dataclasses.replace(stream, t=t)))
    restart = int(np.argmax(np.diff(got) < 0)) + 1
    assert restart > 1
    assert np.all(np.diff(got[restart:]) <= EVERY_S + 0.1)
    assert got[-1] >= t[-1] - EVERY_S - 0.1
