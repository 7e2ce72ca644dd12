"""The console of ``margcal replay``: the progress bar never shares a line with a timeline or log line.

The command runs in a child process on a pseudo-terminal (the bar shows only on a terminal), with the
bar redrawn after every message (``TQDM_MININTERVAL=0``) and INFO logging on; the captured output is
rendered as a terminal would (``\\r`` returns to the start of the line, later text overwrites) and
every rendered line must be either progress or a timeline/log line, never both.
"""

from __future__ import annotations

import os
import re
import select
import struct
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from ros_margcal.recordings.csvfile import write_csv
from ros_margcal.sim import simulation as sim

fcntl = pytest.importorskip("fcntl", reason="needs a POSIX pseudo-terminal")
termios = pytest.importorskip("termios", reason="needs a POSIX pseudo-terminal")

PROGRESS = re.compile(r"replay: *\d+ (msg|messages)|msg/s")
TEXT = re.compile(r"\d+\.\d\d s  (mag|accel)|(DEBUG|INFO|WARNING) ros_margcal")


def render(raw: str) -> list[str]:
    """The lines a terminal shows for ``raw``: per line, each ``\\r`` segment overwrites from column 0."""
    out = []
    for line in raw.replace("\r\n", "\n").split("\n"):
        screen: list[str] = []
        for seg in line.split("\r"):
            screen[: len(seg)] = list(seg)
        out.append("".join(screen).rstrip())
    return out


def test_render_emulates_carriage_returns() -> None:
    assert render("abc\rX\n12\r  \rok\r\n") == ["Xbc", "ok", ""]


def _run_on_pty(args: list[str], env: dict[str, str]) -> str:
    master, slave = os.openpty()
    fcntl.ioctl(slave, termios.TIOCSWINSZ, struct.pack("HHHH", 40, 120, 0, 0))  # a new pty is 0 x 0: no bar fits
    proc = subprocess.Popen(args, stdin=subprocess.DEVNULL, stdout=slave, stderr=slave, env=env, close_fds=True)
    os.close(slave)
    chunks = []
    try:
        while True:
            ready, _, _ = select.select([master], [], [], 120.0)
            if not ready:
                proc.kill()
                pytest.fail("margcal replay produced no output for 120 s")
            try:
                data = os.read(master, 65536)
            except OSError:  # EIO: the child closed the terminal
                break
            if not data:
                break
            chunks.append(data)
    finally:
        os.close(master)
        proc.wait(timeout=60)
    assert proc.returncode == 0, b"".join(chunks).decode(errors="replace")[-2000:]
    return b"".join(chunks).decode(errors="replace")


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    truth = sim.random_sensor(np.random.default_rng(5), "mag")
    rec = sim.magnetometer_stream(truth, 150.0, 50.0, np.random.default_rng(6), motion="tumble")
    return write_csv(tmp_path_factory.mktemp("console") / "mag.csv", rec)


@pytest.mark.parametrize("status_every", ["2", "0"])
def test_progress_and_timeline_and_log_lines_never_share_a_line(recording: Path, status_every: str) -> None:
    env = {**os.environ, "TQDM_MININTERVAL": "0", "PYTHONUNBUFFERED": "1"}
    code = "import sys; from ros_margcal.cli import main; sys.exit(main(sys.argv[1:]))"
    raw = _run_on_pty([sys.executable, "-c", code, "-v", "replay", str(recording), "--sensor", "mag", "--status-every",
                       status_every], env)  # -v: the calibrator's debug log lines too
    lines = render(raw)
    assert any(PROGRESS.search(x) for x in lines) or PROGRESS.search(raw), "no progress bar was shown"
    assert sum(bool(re.search(r"\d+\.\d\d s  mag", x)) for x in lines) >= (20 if status_every == "2" else 2), "no timeline"
    assert any("DEBUG ros_margcal" in x for x in lines), "no log record was written"
    mixed = [x for x in lines if PROGRESS.search(x) and TEXT.search(x)]
    assert not mixed, f"{len(mixed)} lines mix progress with text, e.g. {mixed[:3]}"


def test_quiet_prints_no_timeline(recording: Path) -> None:
    env = dict(os.environ)
    code = "import sys; from ros_margcal.cli import main; sys.exit(main(sys.argv[1:]))"
    lines = render(_run_on_pty([sys.executable, "-c", code, "replay", str(recording), "--sensor", "mag", "-q"], env))
    assert not any(re.search(r"\d+\.\d\d s  mag", x) for x in lines)
    assert any("final state after" in x for x in lines)


def test_each_event_is_printed_once(recording: Path) -> None:
    """Without -v the timeline alone tells what happened: no log line repeats an event's text."""
    code = "import sys; from ros_margcal.cli import main; sys.exit(main(sys.argv[1:]))"
    done = subprocess.run([sys.executable, "-c", code, "replay", str(recording), "--sensor", "mag", "--status-every", "0"],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    lines = (done.stdout + done.stderr).splitlines()
    events = [x.split("calibrated ", 1)[1] for x in lines if re.search(r"\d+\.\d\d s  mag    calibrated ", x)]
    assert events, "no calibration in the timeline"
    logged = [x for x in lines if re.match(r"(DEBUG|INFO|WARNING) ros_margcal", x)]
    assert not [x for x in logged if any(e in x for e in events)], logged[:3]
    assert all(sum(e in x for x in lines) == 1 for e in events)
