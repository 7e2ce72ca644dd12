"""The ``margcal`` command: one console script, one subcommand per offline job.

Each subcommand lives in its own module of this package and adds itself with ``register``; the
benchmarks live in ``ros_margcal.bench`` and run as ``margcal bench AREA [--quick]``.
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys
from collections.abc import Sequence
from pathlib import Path

from .. import __version__
from ..model.errors import ConfigError, MargCalError, one_line

__all__ = ["check_paths", "main", "plot_file"]

PLOT_SUFFIXES = (".png", ".pdf", ".svg", ".svgz", ".jpg", ".jpeg", ".tif", ".tiff", ".webp", ".eps", ".ps")
"""What ``--plot FILE`` may end with: the formats matplotlib's Agg backend writes (checked before the job runs)."""


def plot_file(value: str) -> Path:
    """``--plot FILE``'s argparse type: a path whose suffix names an image format matplotlib writes, told at once
    (not after a replay or an evaluation, as matplotlib's own "Format 'txt' is not supported")."""
    path = Path(value)
    if path.suffix.lower() not in PLOT_SUFFIXES:
        msg = f"{value!r}: a plot file must end with one of {', '.join(PLOT_SUFFIXES)}"
        raise argparse.ArgumentTypeError(msg)
    if path.is_dir():
        msg = f"{value!r} is a directory; give a file name such as {path / 'plot.png'}"
        raise argparse.ArgumentTypeError(msg)
    return path


def check_paths(inputs: Sequence[tuple[str, Path | None]], outputs: Sequence[tuple[str, Path | None]], *,
                folders: Sequence[str] = ()) -> None:
    """Refuse at once (ConfigError, before any work) an output that is an input, lies inside an input folder (a
    rosbag2 directory) or is another output, each named (label, path): the write would destroy what is read or
    written; and an output whose folder cannot be written (found after a fit, as a temporary file's name, before).

    ``folders``: the labels of outputs that are folders to fill (``diagnose --out``), not files."""
    seen: list[tuple[str, Path, Path]] = []
    read = [(label, path, _real(path)) for label, path in inputs if path is not None]
    for label, path in outputs:
        if path is None:
            continue
        real = _real(path)
        for in_label, in_path, in_real in read:
            if real == in_real:
                raise ConfigError(f"{label} {path} is {in_label} {in_path}: writing it would destroy what is read; "
                                  "choose another file")
            if in_real.is_dir() and real.is_relative_to(in_real):
                raise ConfigError(f"{label} {path} lies inside {in_label} {in_path}, a folder that is read: writing it "
                                  "would change the recording; choose a file outside it")
        for out_label, out_path, out_real in seen:
            if real == out_real:
                raise ConfigError(f"{label} {path} and {out_label} {out_path} are the same file: one would overwrite "
                                  "the other; give two files")
        _check_writable(label, path, folder=label in folders)
        seen.append((label, path, real))


def _real(path: Path) -> Path:
    """``path`` absolute, its symbolic links followed (a link to the recording is the recording)."""
    return Path(os.path.realpath(path))


def _check_writable(label: str, path: Path, *, folder: bool) -> None:
    """ConfigError unless ``path`` (a file, or a ``folder`` to create or fill) can be written: the nearest folder
    that exists on its way must be a folder this process may write in."""
    if folder and path.exists() and not path.is_dir():
        raise ConfigError(f"{label} {path} is a file, not a folder; give a folder for the output")
    if not folder and path.is_dir():
        raise ConfigError(f"{label} {path} is a folder; give a file name such as {path / 'out'}")
    near = Path(os.path.abspath(path if folder else path.parent))
    while not near.exists() and near != near.parent:
        near = near.parent
    if not near.is_dir():
        raise ConfigError(f"{label} {path}: {near} is not a folder")
    if not os.access(near, os.W_OK | os.X_OK):
        raise ConfigError(f"{label} {path}: cannot write in {near} (no permission, or a read-only file system)")


_COMMAND_MODULES = ("simulate", "calibrate", "replay", "validator", "diagnose", "demo", "watch")
BENCH_AREAS = ("fitting", "coverage", "pipeline", "diagnosis")


def _run_bench(args: argparse.Namespace) -> int:
    module = importlib.import_module(f"ros_margcal.bench.{args.area}")
    return int(module.main(list(args.bench_args)))



_PASSTHROUGH = {"bench": 2, "diagnose-benchmark": 1}
"""Commands whose remaining words go to a benchmark's own parser, and how many words (with the command) are theirs."""


def _passthrough(words: list[str]) -> tuple[list[str], list[str] | None]:
    """The words ``margcal`` parses and those a benchmark command passes on unparsed (None: not such a command):
    an argparse REMAINDER takes nothing when its first word is an option (``diagnose-benchmark --quick``)."""
    for i, word in enumerate(words):
        if not word.startswith("-"):
            n = _PASSTHROUGH.get(word)
            if n is None or "-h" in words[i + 1 : i + n] or "--help" in words[i + 1 : i + n]:
                return words, None
            return words[: i + n], words[i + n :]
    return words, None


def build_parser() -> argparse.ArgumentParser:
    """The argument parser with every subcommand registered."""

    parser = argparse.ArgumentParser(
        prog="margcal",
        description="Offline tools of ros_margcal: simulate, calibrate, replay, validators, diagnosis, benchmarks.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="log debug messages")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in _COMMAND_MODULES:
        importlib.import_module(f"{__name__}.{name}").register(sub)
    bench = sub.add_parser("bench", help="run a benchmark; figures are ratios against a baseline of the same run")
    bench.add_argument("area", choices=BENCH_AREAS)
    bench.add_argument("bench_args", nargs=argparse.REMAINDER, help="passed on, e.g. --quick")
    bench.set_defaults(func=_run_bench)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``margcal``; returns the exit code (2 for bad input, 1 for other failures).

    Bad input (any MargCalError) and a file the system refuses (OSError: a full disk, no permission)
    are reported on one line, never as a traceback; a traceback is left for bugs.
    """
    words = list(sys.argv[1:] if argv is None else argv)
    own, passed = _passthrough(words)
    args = build_parser().parse_args(own)
    if passed is not None:
        args.bench_args = passed
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    try:
        return int(args.func(args))
    except MargCalError as exc:
        print(f"margcal {args.command}: error: {one_line(exc)}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"margcal {args.command}: error: {one_line(exc)}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"margcal {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
