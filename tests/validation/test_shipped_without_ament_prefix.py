"""With ament_index_python importable but AMENT_PREFIX_PATH unset (ROS from pip, a half-sourced shell), the
shipped validator is still found beside the package (it used to stop replay and diagnose with an OSError)."""

from __future__ import annotations

import importlib.util

import pytest

from ros_margcal.validation.shipped import default_validator_candidates, load_default_validator


def test_shipped_validator_loads_without_ament_prefix_path(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("AMENT_PREFIX_PATH", raising=False)
    if importlib.util.find_spec("ament_index_python") is not None:  # the case of the defect: the index asked, refusing
        from ament_index_python.packages import get_package_share_directory

        with pytest.raises(OSError):
            get_package_share_directory("ros_margcal")
    assert default_validator_candidates()
    assert load_default_validator().inputs
