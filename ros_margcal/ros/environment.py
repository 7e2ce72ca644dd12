"""The environment a ROS 2 installed from PyPI wheels needs (no rclpy).

The ``ros-jazzy-*`` wheels put the ament index under the virtual environment's prefix
(``<venv>/share/ament_index``) but no ``setup.bash`` sets ``AMENT_PREFIX_PATH`` to it, and
``ament_index_python`` refuses to look anything up without it. A sourced ROS 2 (apt, a colcon
workspace) sets it already and is left alone.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

__all__ = ["use_venv_ament_prefix"]


def use_venv_ament_prefix() -> bool:
    """Set ``AMENT_PREFIX_PATH`` to ``sys.prefix`` when it is unset and the prefix holds an ament index.

    Returns True when it set the variable. Call it before ``rclpy.init`` and ament index look-ups.
    """
    if os.environ.get("AMENT_PREFIX_PATH"):
        return False
    if not (Path(sys.prefix) / "share" / "ament_index").is_dir():
        return False
    os.environ["AMENT_PREFIX_PATH"] = sys.prefix
    return True
