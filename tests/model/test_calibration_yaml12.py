"""Calibration YAML read with YAML 1.2's floats: ``5e-05`` (no dot) is a number, as ROS 2's parser reads it.

PyYAML follows YAML 1.1, whose floats need a dot and a signed exponent, so a hand-written ``norm: 5e-05`` was
refused as a string. Plain scalars in YAML 1.2's float syntax are floats now; quoted strings stay strings
(and are refused as today), and a string that looks like a number is quoted when written.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ros_margcal.model.calibration import Calibration
from ros_margcal.model.calibration_file import calibration_from_yaml, calibration_to_yaml, load_calibrations
from ros_margcal.model.errors import CalibrationFileError

V1 = """margcal:
  ros__parameters:
    calibration:
      mag:
        format_version: 1
        model: sym
        method: truth
        sensor: mag
        unit: T
        offset: [{offset}]
        matrix: [{matrix}]
        norm: {norm}
        stamp: 0
"""
OFFSET = "3.25e-06, -3.4e-06, 1.6e-05"
MATRIX = "0.97, -0.0085, -0.0015, -0.0085, 0.96, -0.0165, -0.0015, -0.0165, 0.99"


def _v1(tmp_path: Path, *, offset: str = OFFSET, matrix: str = MATRIX, norm: str = "5.0e-05") -> Path:
    path = tmp_path / "truth.yaml"
    path.write_text(V1.format(offset=offset, matrix=matrix, norm=norm))
    return path


@pytest.mark.parametrize(
    ("norm", "value"), [("5e-05", 5e-05), ("5E-5", 5e-05), ("5.0e-5", 5e-05), ("+5e-5", 5e-05), (".5e-4", 5e-05)]
)
def test_a_plain_number_in_yaml_1_2_syntax_is_a_float(tmp_path: Path, norm: str, value: float) -> None:
    """Exponents without a dot or a sign (YAML 1.2, ROS 2) are read as floats, not refused as strings."""
    cal = load_calibrations(_v1(tmp_path, norm=norm, offset="1e-6, -2E-6, 3e-6"))["mag"]
    assert cal.norm == value
    np.testing.assert_array_equal(cal.offset, [1e-6, -2e-6, 3e-6])


def test_a_huge_plain_number_is_refused_as_absurd_not_as_a_string(tmp_path: Path) -> None:
    """1e200 in the matrix and 1e300 in the offset are numbers now: refused for their size, naming the field."""
    for kw, field in (({"matrix": "1e200,0,0, 0,1e200,0, 0,0,1e200"}, "matrix"), ({"offset": "1e300, 0, 0"}, "offset")):
        with pytest.raises(CalibrationFileError, match=field) as info:
            load_calibrations(_v1(tmp_path, **kw))
        assert "got str" not in str(info.value)


@pytest.mark.parametrize("norm", ["'5e-05'", '"5e-05"', "5e-05x", "5_0e-6", "1e5.0"])
def test_quoted_and_other_strings_are_still_refused(tmp_path: Path, norm: str) -> None:
    """Quoted numbers and what YAML 1.2 does not call a float stay strings (or ints) and are refused."""
    with pytest.raises(CalibrationFileError, match="'norm'"):
        load_calibrations(_v1(tmp_path, norm=norm))


def test_format_version_stays_an_int() -> None:
    """Integers are untouched: format_version 1 stays an int (a float 1.0 is refused), also in a topic's YAML text."""
    text = V1.format(offset=OFFSET, matrix=MATRIX, norm="5e-05")
    assert calibration_from_yaml(text).norm == 5e-05


def test_a_string_that_looks_like_a_number_round_trips() -> None:
    """A method or unit text such as '1e5' is written quoted, so it is read back as the same string."""
    cal = Calibration(np.zeros(3), np.eye(3), 5e-05, method="1e5", sensor="mag", unit="T")
    text = calibration_to_yaml(cal)
    assert "'1e5'" in text
    assert calibration_from_yaml(text).method == "1e5"
