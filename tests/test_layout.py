"""The house rules of docs/ARCHITECTURE.md, checked on the source: layers point down, no import circle,
no import inside a function body except an optional dependency, and today's public names stay."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

import ros_margcal

ROOT = Path(ros_margcal.__file__).resolve().parent
OPTIONAL = {"rosbags", "matplotlib", "pygeomag", "ament_index_python", "rclpy", "builtin_interfaces", "diagnostic_msgs", "geometry_msgs",
            "sensor_msgs", "std_msgs"}
"""Imported where they are used, with a comment saying why: none is needed by the online core."""

ALLOWED = {
    "model": set(),
    "coverage": {"model"},
    "validation": {"model"},
    "recordings": {"model"},
    "stream": {"model", "coverage", "validation", "recordings"},
    "ros": {"model", "coverage", "validation", "stream"},
    "sim": {"model", "recordings"},
    "training": {"model", "coverage", "validation", "sim"},
    "diagnosis": {"model", "coverage", "validation", "sim", "training", "recordings"},
    "bench": {"model", "coverage", "validation", "recordings", "stream", "ros", "sim", "training", "diagnosis"},
    "cli": {"<top>", "model", "coverage", "validation", "recordings", "stream", "sim", "training", "diagnosis", "bench"},
}
"""Which sub-packages each one may import (its own modules always)."""

PUBLIC = {
    "EFFECTS", "METHODS", "MODELS", "PATTERNS", "Calibration", "CalibrationFileError", "ConfigError", "ConvergenceError",
    "DegenerateDataError", "DirectionBuffer", "FitStats", "FuzzyValidator", "InactivityGate", "Indicators", "InputError",
    "MargCalError", "PipelineConfig", "Recording", "RecordingError", "SensorCalibrator", "Status", "ThresholdValidator",
    "__version__", "compute_indicators", "directions", "fit", "load_calibrations", "load_default_validator",
    "random_sensor", "read_recording", "save_calibrations", "simulate", "write_bag", "write_csv",
}
"""The top-level names of the flat layout before sub-packages (0.1.0): they must keep working."""


def _module(path: Path) -> str:
    parts = ["ros_margcal", *path.relative_to(ROOT).with_suffix("").parts]
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {_module(p): p for p in ROOT.rglob("*.py")}


def _imports(name: str) -> list[tuple[str, ast.AST, bool]]:
    """(imported module, node, at top level) for every import of a ros_margcal module in ``name``."""
    path = MODULES[name]
    tree = ast.parse(path.read_text())
    top = {id(n) for n in tree.body}
    pkg = name if path.name == "__init__.py" else name.rpartition(".")[0]
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg.split(".")[: len(pkg.split(".")) - node.level + 1]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            subs = [f"{target}.{a.name}" for a in node.names if f"{target}.{a.name}" in MODULES]
            for t in subs or [target]:
                out.append((t, node, id(node) in top))
        elif isinstance(node, ast.Import):
            out += [(a.name, node, id(node) in top) for a in node.names]
    return out


def _layer(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 and parts[1] in ALLOWED else "<top>"


def test_today_public_names_are_kept() -> None:
    """Every name of the flat layout still imports from ros_margcal."""
    missing = sorted(n for n in PUBLIC if not hasattr(ros_margcal, n))
    assert not missing
    assert PUBLIC <= set(ros_margcal.__all__)


@pytest.mark.parametrize("name", sorted(MODULES))
def test_layers_point_down(name: str) -> None:
    """A module imports only from the sub-packages below its own; nothing imports the node."""
    me = _layer(name)
    for target, node, _ in _imports(name):
        if not target.startswith("ros_margcal"):
            continue
        assert target != "ros_margcal.ros.node", f"{name}:{node.lineno} imports the node"
        other = _layer(target)
        if me in ALLOWED and other != me:
            assert other in ALLOWED[me], f"{name}:{node.lineno} ({me}) imports {target} ({other})"


@pytest.mark.parametrize("name", sorted(MODULES))
def test_no_import_inside_a_function_except_optional_dependencies(name: str) -> None:
    """Imports sit at the top of a module; an optional dependency may be imported where it is used."""
    for target, node, top in _imports(name):
        if top or target.split(".")[0] in OPTIONAL or target == "__future__":
            continue
        if isinstance(node, ast.ImportFrom) and target.startswith("ros_margcal") and node.col_offset == 4 and \
                _inside_type_checking(MODULES[name], node):
            continue
        pytest.fail(f"{name}:{node.lineno} imports {target} inside a function or block")


def _inside_type_checking(path: Path, node: ast.AST) -> bool:
    tree = ast.parse(path.read_text())
    for n in tree.body:
        if isinstance(n, ast.If) and "TYPE_CHECKING" in ast.unparse(n.test):
            return any(c.lineno == node.lineno for c in ast.walk(n))
    return False


def test_no_import_circle() -> None:
    """The module graph (a sub-module import also runs its package's __init__) has no cycle."""
    graph: dict[str, set[str]] = {m: set() for m in MODULES}
    for m in MODULES:
        for target, _, _ in _imports(m):
            parts = target.split(".")
            for k in range(1, len(parts) + 1):
                t = ".".join(parts[:k])
                if t in MODULES and t != m and not m.startswith(t + "."):
                    graph[m].add(t)
    state: dict[str, int] = {}

    def visit(m: str, path: list[str]) -> None:
        state[m] = 1
        for t in graph[m]:
            if state.get(t) == 1:
                pytest.fail("import circle: " + " -> ".join([*path[path.index(t):], t]))
            if t not in state:
                visit(t, [*path, t])
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m, [m])


@pytest.mark.parametrize("pkg", sorted(ALLOWED))
def test_every_subpackage_has_a_face(pkg: str) -> None:
    """Each sub-package's __init__ has a docstring and a sorted __all__ of names it really exports."""
    path = ROOT / pkg / "__init__.py"
    tree = ast.parse(path.read_text())
    assert ast.get_docstring(tree), f"{pkg}/__init__.py has no docstring"
    if pkg in ("bench", "cli"):
        return
    node = next(n for n in tree.body if isinstance(n, ast.Assign) and ast.unparse(n.targets[0]) == "__all__")
    names = [e.value for e in node.value.elts]
    assert names == sorted(names, key=lambda s: (0 if s.isupper() else 1 if s[0].isupper() else 2, s))
    mod = __import__(f"ros_margcal.{pkg}", fromlist=["_"])
    assert all(hasattr(mod, n) for n in names)
