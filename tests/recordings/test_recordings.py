"""Tests of reading and writing recordings (CSV, rosbag2) and of ``margcal simulate``."""

from __future__ import annotations

import argparse
import importlib.util
from pathlib import Path

import numpy as np
import pytest

from ros_margcal.cli import simulate as simulate_cli
from ros_margcal.model.calibration_file import load_calibrations
from ros_margcal.model.errors import ConfigError, RecordingError
from ros_margcal.recordings.bag import FRAME_ID, bag_topics, iter_bag_messages, write_bag
from ros_margcal.recordings.csvfile import write_csv
from ros_margcal.recordings.read import read_recording
from ros_margcal.recordings.recording import Recording
from ros_margcal.sim.simulation import magnetometer_stream, random_sensor, tumbling, tumbling_motion

SEED = 7


@pytest.fixture(scope="module")
def imu_pair() -> tuple[Recording, Recording]:
    """A short IMU: accelerometer + gyro at 100 Hz (with temperature) and magnetometer at 50 Hz, one motion."""
    rng = np.random.default_rng(SEED)
    motion = tumbling_motion(12.0, 100.0, rng)
    acc = tumbling(random_sensor(rng, "accel"), 12.0, 100.0, rng, motion=motion, effects={"temperature": 0.001})
    mag = magnetometer_stream(random_sensor(rng, "mag"), 12.0, 50.0, rng, motion=motion)
    return acc, mag


def _write(path: Path, text: str) -> Path:
    path.write_text(text, encoding="utf-8")
    return path


# -- CSV -------------------------------------------------------------------------------------------


def test_csv_round_trip_is_exact(tmp_path: Path, imu_pair: tuple[Recording, Recording]) -> None:
    """write_csv then read_recording gives the same t, raw, temp and gyro, bit for bit."""
    acc, _ = imu_pair
    path = write_csv(tmp_path / "imu_acc.csv", acc)
    assert path.read_text().splitlines()[0] == "t,x,y,z,temp,gx,gy,gz"
    back = read_recording(path)
    np.testing.assert_array_equal(back.t, acc.t)
    np.testing.assert_array_equal(back.raw, acc.raw)
    np.testing.assert_array_equal(back.temp, acc.temp)
    np.testing.assert_array_equal(back.gyro, acc.gyro)
    assert back.sensor == "accel" and back.truth is None


def test_csv_minimal_columns_in_any_order(tmp_path: Path) -> None:
    """Columns may come in any order, with spaces and extra columns; sensor can be given."""
    path = _write(tmp_path / "plain.csv", "z, y ,x,t,note\n3,2,1,0.0,a\n6,5,4,0.5,b\n")
    rec = read_recording(path, sensor="mag")
    np.testing.assert_array_equal(rec.raw, [[1, 2, 3], [4, 5, 6]])
    np.testing.assert_array_equal(rec.t, [0.0, 0.5])
    assert rec.gyro is None and rec.temp is None and rec.sensor == "mag"


def test_csv_sort_option_sorts_backwards_times(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    """sort=True sorts out-of-order samples stably and logs how many steps went backwards."""
    path = _write(tmp_path / "b.csv", "t,x,y,z\n0,1,1,1\n2,2,2,2\n1,3,3,3\n2,4,4,4\n")
    rec = read_recording(path, sort=True)
    np.testing.assert_array_equal(rec.t, [0, 1, 2, 2])
    np.testing.assert_array_equal(rec.raw[:, 0], [1, 3, 2, 4])
    assert "1 backwards" in caplog.text


@pytest.mark.parametrize(
    ("name", "text", "match"),
    [
        ("empty.csv", "", "is empty"),
        ("blank.csv", "\n\n", "is empty"),
        ("header_only.csv", "t,x,y,z\n", "no samples"),
        ("bad_header.csv", "time,x,y,z\n0,1,2,3\n", r"bad header.*missing column\(s\) \['t'\]"),
        ("no_header.csv", "0,1,2,3\n1,1,2,3\n", "bad header"),
        ("gyro_part.csv", "t,x,y,z,gx,gy\n0,1,2,3,0,0\n", "gx,gy,gz"),
        ("repeated.csv", "t,x,y,z,x\n0,1,2,3,4\n", "repeated column"),
        ("text_cell.csv", "t,x,y,z\n0,1,2,3\n1,1,abc,3\n", r"line 3, column 'y': 'abc' is not a number"),
        ("empty_cell.csv", "t,x,y,z\n0,1,,3\n", "line 2, column 'y'"),
        ("nan_cell.csv", "t,x,y,z\n0,1,2,3\n1,nan,2,3\n", r"line 3, column 'x' is nan"),
        ("inf_time.csv", "t,x,y,z\ninf,1,2,3\n", "column 't' is inf"),
        ("ragged.csv", "t,x,y,z\n0,1,2\n", "line 2 has 3 cells"),
        ("backwards.csv", "t,x,y,z\n0,1,2,3\n2,1,2,3\n1,1,2,3\n", r"time goes backwards at 1 place\(s\).*sort=True"),
    ],
)
def test_csv_errors(tmp_path: Path, name: str, text: str, match: str) -> None:
    """Every unusable CSV raises RecordingError saying what is wrong and where."""
    with pytest.raises(RecordingError, match=match):
        read_recording(_write(tmp_path / name, text))


def test_csv_binary_garbage(tmp_path: Path) -> None:
    """A binary file that is not UTF-8 text is refused."""
    path = tmp_path / "junk.csv"
    path.write_bytes(b"\xff\xfe\x00\x81garbage")
    with pytest.raises(RecordingError, match="cannot read"):
        read_recording(path)


# -- rosbag2 ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["imu.mcap", "imu.db3", "bagdir"])
def test_bag_round_trip(tmp_path: Path, imu_pair: tuple[Recording, Recording], name: str) -> None:
    """write_bag then read_recording gives the same samples per sensor (file or directory bag)."""
    acc, mag = imu_pair
    path = write_bag(tmp_path / name, {"/imu/data_raw": acc, "/imu/mag": mag})
    assert path.is_dir() == (name == "bagdir")
    assert bag_topics(path) == {
        "/imu/data_raw": "sensor_msgs/msg/Imu",
        "/imu/data_raw/temperature": "sensor_msgs/msg/Temperature",
        "/imu/mag": "sensor_msgs/msg/MagneticField",
    }
    a = read_recording(path, sensor="accel")
    m = read_recording(path, topic="/imu/mag")
    np.testing.assert_allclose(a.t, acc.t, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(a.raw, acc.raw)
    np.testing.assert_array_equal(a.gyro, acc.gyro)
    np.testing.assert_allclose(a.temp, acc.temp, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(m.raw, mag.raw)
    assert (a.sensor, a.unit, m.sensor, m.unit) == ("accel", "m/s^2", "mag", "T")
    assert m.gyro is None and m.temp is None


def test_bag_messages_follow_rep145(tmp_path: Path, imu_pair: tuple[Recording, Recording]) -> None:
    """Imu without orientation (cov[0] = -1), frame imu_link, stamps from t; no gyro -> cov[0] = -1."""
    acc, mag = imu_pair
    no_gyro = Recording(t=acc.t[:50], raw=acc.raw[:50], sensor="accel")
    path = write_bag(tmp_path / "rep.mcap", {"/imu/data_raw": acc, "/imu/mag": mag, "/other/data_raw": no_gyro})
    seen = {"imu": 0, "mag": 0}
    stream = iter_bag_messages(path, topics={"/imu/data_raw", "/imu/mag"})
    assert iter(stream) is stream  # a generator: streams, does not load everything
    last = -1.0
    for msg in stream:
        assert msg.t >= last
        last = msg.t
        seen[msg.kind] += 1
        assert msg.msg.header.frame_id == FRAME_ID
        stamp = msg.msg.header.stamp
        assert stamp.sec + stamp.nanosec * 1e-9 == pytest.approx(msg.t, abs=1e-9)
        if msg.kind == "imu":
            assert msg.msg.orientation_covariance[0] == -1.0
            assert msg.gyro is not None and msg.msg.angular_velocity_covariance[0] == 0.0
            np.testing.assert_array_equal(msg.xyz, [msg.msg.linear_acceleration.x, msg.msg.linear_acceleration.y,
                                                    msg.msg.linear_acceleration.z])
        else:
            assert msg.gyro is None
    assert seen == {"imu": len(acc), "mag": len(mag)}
    first = next(iter_bag_messages(path))
    t, kind, xyz, gyro, msg = first  # the contract's 5-tuple
    assert (t, kind, msg) == (first.t, first.kind, first.msg) and xyz is first.xyz and gyro is first.gyro
    assert {m.topic for m in iter_bag_messages(path)} == {"/imu/data_raw", "/imu/mag", "/other/data_raw"}
    other = list(iter_bag_messages(path, topics={"/other/data_raw"}))
    assert len(other) == 50 and all(m.gyro is None for m in other)
    assert other[0].msg.angular_velocity_covariance[0] == -1.0
    assert read_recording(path, topic="/other/data_raw").gyro is None


def test_bag_zero_stamp_falls_back_to_receive_time(tmp_path: Path) -> None:
    """A message with an unset (zero) header stamp gets the bag's receive time."""
    rec = Recording(t=np.array([0.0, 0.5, 1.0]), raw=np.ones((3, 3)), sensor="mag")
    path = write_bag(tmp_path / "z.mcap", {"/imu/mag": rec})
    np.testing.assert_allclose(read_recording(path).t, rec.t)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"sensor": "gyro"}, "sensor must be"),
        ({"topic": "/nope"}, "no Imu or MagneticField topic '/nope'"),
        ({"topic": "/imu/data_raw/temperature"}, "no Imu or MagneticField topic"),
        ({"topic": "/imu/mag", "sensor": "accel"}, "not a 'accel' sensor"),
        ({}, "several matching topics"),
    ],
)
def test_bag_topic_errors(tmp_path: Path, imu_pair: tuple[Recording, Recording], kwargs: dict[str, str], match: str) -> None:
    """Bags refuse ambiguous or missing topics with the list of what they hold."""
    acc, mag = imu_pair
    path = write_bag(tmp_path / "t.mcap", {"/imu/data_raw": acc, "/imu/mag": mag})
    with pytest.raises(RecordingError, match=match):
        read_recording(path, **kwargs)


def test_bag_without_the_sensor(tmp_path: Path, imu_pair: tuple[Recording, Recording]) -> None:
    """A mag-only bag has no accelerometer to read."""
    path = write_bag(tmp_path / "m.db3", {"/imu/mag": imu_pair[1]})
    with pytest.raises(RecordingError, match="has no Imu topic"):
        read_recording(path, sensor="accel")
    with pytest.raises(RecordingError, match="no Imu or MagneticField topic among"):
        list(iter_bag_messages(path, topics={"/imu/data_raw"}))


def test_bag_topic_without_messages(tmp_path: Path) -> None:
    """A topic that holds no messages is an empty recording."""
    empty = Recording(t=np.zeros(0), raw=np.zeros((0, 3)), sensor="mag")
    path = write_bag(tmp_path / "empty.mcap", {"/imu/mag": empty})
    with pytest.raises(RecordingError, match="holds no messages"):
        read_recording(path)


def test_bag_backwards_stamps_refused_or_sorted(tmp_path: Path) -> None:
    """Header stamps going backwards (in receive order) are refused unless sort=True."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    types_ = store.types
    path = tmp_path / "back"
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conn = writer.add_connection("/imu/mag", "sensor_msgs/msg/MagneticField", typestore=store)
        for i, stamp in enumerate([1.0, 3.0, 2.0, 4.0]):
            header = types_["std_msgs/msg/Header"](stamp=types_["builtin_interfaces/msg/Time"](sec=int(stamp), nanosec=0),
                                                  frame_id="imu_link")
            msg = types_["sensor_msgs/msg/MagneticField"](header=header,
                                                          magnetic_field=types_["geometry_msgs/msg/Vector3"](x=float(i), y=0.0, z=0.0),
                                                          magnetic_field_covariance=np.zeros(9))
            writer.write(conn, (10 + i) * 10**9, store.serialize_cdr(msg, conn.msgtype))
    assert [m.t for m in iter_bag_messages(path)] == [1.0, 3.0, 2.0, 4.0]  # streamed as recorded
    with pytest.raises(RecordingError, match="time goes backwards at 1 place"):
        read_recording(path)
    rec = read_recording(path, sort=True)
    np.testing.assert_array_equal(rec.t, [1, 2, 3, 4])
    np.testing.assert_array_equal(rec.raw[:, 0], [0, 2, 1, 3])


@pytest.mark.parametrize("name", ["junk.mcap", "junk.db3", "junkdir"])
def test_unreadable_bag(tmp_path: Path, name: str) -> None:
    """Files that are not bags raise RecordingError, not a rosbags or sqlite exception."""
    path = tmp_path / name
    if name.endswith("dir"):
        path.mkdir()
        (path / "metadata.yaml").write_text("rosbag2_bagfile_information: {version: 99}\n")
    else:
        path.write_bytes(b"this is not a bag at all" * 10)
    with pytest.raises(RecordingError, match="not a readable rosbag2 bag"):
        read_recording(path)


@pytest.mark.parametrize("path", ["missing.csv", "missing.mcap", "missing_dir/"])
def test_missing_recording(tmp_path: Path, path: str) -> None:
    """A missing file raises RecordingError naming it."""
    with pytest.raises(RecordingError, match="does not exist"):
        read_recording(tmp_path / path)


def test_topic_on_csv_is_refused(tmp_path: Path) -> None:
    """topic= makes no sense for a CSV."""
    path = _write(tmp_path / "a.csv", "t,x,y,z\n0,1,2,3\n")
    with pytest.raises(RecordingError, match="topic= applies to rosbag2"):
        read_recording(path, topic="/imu/mag")


def test_write_bag_errors(tmp_path: Path, imu_pair: tuple[Recording, Recording]) -> None:
    """write_bag refuses existing targets (unless overwrite), unknown storage and unlabelled recordings."""
    acc, _ = imu_pair
    path = write_bag(tmp_path / "x.mcap", {"/imu/data_raw": acc})
    with pytest.raises(RecordingError, match="exists already"):
        write_bag(path, {"/imu/data_raw": acc})
    write_bag(path, {"/imu/data_raw": acc.slice(slice(0, 10))}, overwrite=True)
    assert len(read_recording(path)) == 10
    with pytest.raises(RecordingError, match="storage must be"):
        write_bag(tmp_path / "d", {"/a": acc}, storage="rosbag1")
    with pytest.raises(RecordingError, match="set 'mag' or 'accel'"):
        write_bag(tmp_path / "y.mcap", {"/a": Recording(t=acc.t, raw=acc.raw)})
    assert not (tmp_path / "y.mcap").exists()
    with pytest.raises(RecordingError, match="recs is empty"):
        write_bag(tmp_path / "z.mcap", {})
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.mcap"]  # no temporary leftovers


# -- real recordings -------------------------------------------------------------------------------


def test_real_csv_recordings(real_data_dir: Path) -> None:
    """Every real CSV reads: finite, non-decreasing time, sensor from the name, plausible norms."""
    files = sorted(real_data_dir.glob("*.csv"))
    assert len(files) >= 10
    for path in files:
        rec = read_recording(path)
        assert len(rec) > 1000, path.name
        assert np.isfinite(rec.raw).all() and np.all(np.diff(rec.t) >= 0)
        expected = "mag" if path.stem.endswith("_mag") else "accel"
        assert rec.sensor == expected, path.name
        norms = np.linalg.norm(rec.raw, axis=1)
        assert np.median(norms) > 0
    acc = read_recording(real_data_dir / "sunsided_mpu6050_unmoved-with-x-pointing-forward_acc.csv")
    assert np.median(np.linalg.norm(acc.raw, axis=1)) == pytest.approx(1.0, abs=0.06)  # in g
    static = read_recording(real_data_dir / "sunsided_hmc5883l_static_10min_mag.csv")
    assert static.t[-1] > 550.0  # ten minutes


# -- margcal simulate ------------------------------------------------------------------------------


def _run_cli(*argv: str) -> int:
    parser = argparse.ArgumentParser()
    simulate_cli.register(parser.add_subparsers())
    args = parser.parse_args(["simulate", *argv])
    return int(args.func(args))


def test_cli_simulate_csv_with_truth(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A cap pattern to CSV, with its true calibration: the truth calibrates the data to the norm."""
    out, truth = tmp_path / "cap.csv", tmp_path / "truth.yaml"
    code = _run_cli(str(out), "--sensor", "mag", "--pattern", "cap", "--param", "half_angle_deg=40",
                    "--param", "axis=(1,0,0)", "-n", "120", "--noise", "0", "--seed", "3", "--truth", str(truth))
    assert code == 0 and "wrote" in capsys.readouterr().out
    rec = read_recording(out, sensor="mag")  # a CSV does not say its sensor; cap.csv has no hint in its name
    cal = load_calibrations(truth)["mag"]
    assert len(rec) == 120 and rec.sensor == "mag"
    np.testing.assert_allclose(cal.norm_error(rec.raw), 0.0, atol=1e-12)
    h = cal.apply(rec.raw) / cal.norm
    assert np.degrees(np.arccos(h[:, 0].min())) <= 40.0 + 1e-6


def test_cli_simulate_imu_bag_with_effects(tmp_path: Path) -> None:
    """--sensor imu writes both topics from one motion; effects land on the sensors they apply to."""
    out = tmp_path / "imu.mcap"
    assert _run_cli(str(out), "--sensor", "imu", "--pattern", "tumbling", "--duration", "8", "--rate", "50",
                    "--effect", "motion_leak=0.1", "--effect", "disturbance=") == 0
    assert set(bag_topics(out)) == {"/imu/data_raw", "/imu/mag"}
    assert len(read_recording(out, sensor="accel")) == 400
    assert len(read_recording(out, sensor="mag")) == 200
    first = read_recording(out, sensor="mag").raw
    out2 = tmp_path / "imu2.mcap"
    _run_cli(str(out2), "--sensor", "imu", "--pattern", "tumbling", "--duration", "8", "--rate", "50",
             "--effect", "motion_leak=0.1", "--effect", "disturbance=")
    np.testing.assert_array_equal(read_recording(out2, sensor="mag").raw, first)  # seeded


def test_cli_simulate_hard_iron_jump(tmp_path: Path) -> None:
    """--jump-at puts a hard-iron jump in the magnetometer stream; the truth file has both calibrations."""
    out, truth = tmp_path / "jump.mcap", tmp_path / "truth.yaml"
    assert _run_cli(str(out), "--sensor", "imu", "--pattern", "tumbling", "--duration", "20", "--rate", "50",
                    "--noise", "0", "--jump-at", "10", "--jump-size", "0.5", "--truth", str(truth)) == 0
    cals = load_calibrations(truth)
    assert set(cals) == {"accel", "mag_before", "mag_after"} and cals["mag_after"].stamp == 10.0
    shift = np.linalg.norm(cals["mag_after"].offset - cals["mag_before"].offset) / cals["mag_before"].norm
    assert shift == pytest.approx(0.5)
    mag = read_recording(out, sensor="mag")
    before, after = mag.t < 10.0, mag.t >= 10.0
    np.testing.assert_allclose(cals["mag_before"].norm_error(mag.raw[before]), 0.0, atol=1e-15)
    np.testing.assert_allclose(cals["mag_after"].norm_error(mag.raw[after]), 0.0, atol=1e-15)


@pytest.mark.parametrize(
    ("argv", "match"),
    [
        (["x.csv", "--sensor", "imu", "--pattern", "tumbling"], "CSV holds one sensor"),
        (["x.csv", "--sensor", "mag", "--jump-at", "5"], "needs a time series"),
        (["x.csv", "--sensor", "accel", "--pattern", "tumbling", "--jump-at", "5"], "magnetometer event"),
        (["x.mcap", "--sensor", "imu"], "needs a time series"),
        (["x.csv", "--sensor", "mag", "--effect", "motion_leak=0.1"], "applies to"),
        (["x.csv", "--pattern", "tumbling", "--param", "k=3"], "--param applies"),
        (["x.csv", "--sensor", "accel", "--pattern", "smooth"], "magnetometer motion"),
        (["x.csv", "--pattern", "cap", "--param", "half_angle_deg=-5"], "half_angle_deg"),
    ],
)
def test_cli_simulate_errors(tmp_path: Path, monkeypatch: pytest.MonkeyPatch, argv: list[str], match: str) -> None:
    """Bad option combinations raise ConfigError (the dispatcher turns it into exit code 2)."""
    monkeypatch.chdir(tmp_path)
    with pytest.raises(ConfigError, match=match):
        _run_cli(*argv)


@pytest.mark.parametrize("effect", ["wobble=1", "noise", "noise=abc"])
def test_cli_simulate_bad_effect_syntax(effect: str, capsys: pytest.CaptureFixture[str]) -> None:
    """Malformed --effect values are argparse errors."""
    with pytest.raises(SystemExit):
        _run_cli("x.csv", "--effect", effect)
    assert "--effect" in capsys.readouterr().err


# -- the shipped example ---------------------------------------------------------------------------


def test_example_recording_matches_its_truth() -> None:
    """The shipped example: an IMU and a magnetometer with a hard-iron jump, consistent with its truth."""
    data = Path(simulate_cli.__file__).resolve().parents[1] / "data"
    bag, truth_file = data / "example_imu.mcap", data / "example_truth.yaml"
    assert bag.exists() and truth_file.exists(), "the example recording must ship in ros_margcal/data (scripts/make_example.py)"
    assert bag.stat().st_size < 4.5e6
    truth = load_calibrations(truth_file)
    acc = read_recording(bag, sensor="accel")
    mag = read_recording(bag, sensor="mag")
    assert acc.gyro is not None and acc.t[-1] >= 240.0
    rest = np.linalg.norm(acc.gyro, axis=1) < 0.02
    assert 0.4 < rest.mean() < 0.8
    err = truth["accel"].norm_error(acc.raw[rest])
    assert np.median(np.abs(err)) < 0.05
    jump = truth["mag_after"].stamp
    for name, sel in (("mag_before", mag.t < jump), ("mag_after", mag.t >= jump)):
        rel = truth[name].norm_error(mag.raw[sel]) / truth[name].norm
        assert np.sqrt(np.mean(rel**2)) < 0.01, name
    wrong = truth["mag_before"].norm_error(mag.raw[mag.t >= jump]) / truth["mag_before"].norm
    assert np.sqrt(np.mean(wrong**2)) > 0.2


def _bag_content(path: Path) -> tuple[list[tuple[str, str]], list[tuple[str, int, str, int, int]], np.ndarray]:
    """What a bag means, not its bytes: (topic, type) per connection; (topic, receive time, frame_id, header stamp)
    per message in order; and every message's float fields (vectors and covariances) as one array.

    The compressed chunks of an .mcap depend on the zstd build pip installs, so the bytes are no criterion; the
    floats may differ in their last bit between CPUs (numpy's SIMD sin, cos and exp), so they are compared to
    a relative 1e-9 by the caller.
    """
    from rosbags.rosbag2 import Reader  # optional dependency, as in the package
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    meta, values = [], []
    with Reader(path) as reader:
        conns = sorted((c.topic, c.msgtype) for c in reader.connections)
        for c, ns, data in reader.messages():
            msg = store.deserialize_cdr(bytes(data), c.msgtype)
            meta.append((c.topic, ns, msg.header.frame_id, msg.header.stamp.sec, msg.header.stamp.nanosec))
            fields = ("orientation", "angular_velocity", "linear_acceleration") if hasattr(msg, "orientation") else ("magnetic_field",)
            vec = [getattr(getattr(msg, f), a) for f in fields for a in ("x", "y", "z", "w") if hasattr(getattr(msg, f), a)]
            covs = [np.asarray(v, float) for k, v in vars(msg).items() if k.endswith("covariance")]
            values.append(np.concatenate([np.asarray(vec, float), *covs]))
    return conns, meta, np.concatenate(values)


def test_make_example_is_deterministic(tmp_path: Path) -> None:
    """scripts/make_example.py reproduces the shipped example: the same messages and the same true calibrations."""
    script = Path(simulate_cli.__file__).resolve().parents[2] / "scripts" / "make_example.py"
    data = script.parents[1] / "ros_margcal" / "data"
    if not script.exists() or not (data / "example_imu.mcap").exists():
        pytest.skip("make_example.py or the example recording is not in this checkout")
    spec = importlib.util.spec_from_file_location("make_example", script)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    bag, truth = module.make(tmp_path)
    conns, messages, values = _bag_content(bag)
    shipped_conns, shipped_messages, shipped_values = _bag_content(data / "example_imu.mcap")
    assert conns == shipped_conns == [("/imu/data_raw", "sensor_msgs/msg/Imu"), ("/imu/mag", "sensor_msgs/msg/MagneticField")]
    assert len(messages) == len(shipped_messages) == 54000
    assert messages == shipped_messages  # topics, receive stamps, frames and header stamps exactly
    assert values.shape == shipped_values.shape
    np.testing.assert_allclose(values, shipped_values, rtol=1e-9, atol=0.0)  # every value, up to the CPU's last bits
    made, shipped = load_calibrations(truth), load_calibrations(data / "example_truth.yaml")
    assert list(made) == list(shipped) == ["accel", "mag_before", "mag_after"]
    for name, cal in made.items():
        mine, theirs = cal.to_dict(), shipped[name].to_dict()
        assert mine.keys() == theirs.keys(), name
        for key, value in mine.items():
            if isinstance(value, (int, float, list)) and not isinstance(value, bool):
                np.testing.assert_allclose(np.asarray(value, float), np.asarray(theirs[key], float), rtol=1e-9, atol=0.0)
            else:
                assert value == theirs[key], (name, key)
