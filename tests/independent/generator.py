"""Independent generator of magnetometer / accelerometer recordings (numpy only).

Deliberately shares no code or modelling choices with ``ros_margcal``: attitude is a unit quaternion
(scalar first, body -> world, ENU world frame) integrated from body rates, the sensor model is written
field-side, ``raw = offset(t) + G(t) @ M @ b_body + noise`` with ``M = (I + A) @ R_mis`` a general
(non-symmetric) matrix, noise is AR(1) (Gauss-Markov) plus white, and effects use their own
parametrisations.  The truth is also given in the package's convention,
``calibrated = W @ (raw - offset)`` with ``W = M^-1``, in the raw units of the recording.

Effect magnitudes (``magnitude=None`` picks ``DEFAULT_MAGNITUDE``; F = field intensity):
  soft_iron       extra field-side matrix perturbation, entries U(-m, m)
  nonlinearity    raw_i += k_i * raw_i**3 / F**2 with |k_i| in [m/2, m]
  temperature     per °C: offset drift m*F (random direction), gain drift U(-m, m); ambient +15 °C ramp
  saturation      per-axis clipping of raw at ±m*F
  quantization    rounding to an LSB of m*F
  bias_drift      random-walk offset drift, largest excursion m*F
  misalignment    sensor axes rotated by m degrees about a random axis (invisible to magnitudes)
  hard_iron_jump  offset steps by a vector of norm m*F at ``t_jump`` (default mid-record)
"""

from __future__ import annotations

import numpy as np

G0 = 9.80665
MOTIONS = ("tumble", "ground", "hemisphere", "band", "static", "rest_and_move", "car")
EFFECTS = ("none", "soft_iron", "nonlinearity", "temperature", "saturation", "quantization",
           "bias_drift", "misalignment", "hard_iron_jump")
DEFAULT_MAGNITUDE = {"none": 0.0, "soft_iron": 0.1, "nonlinearity": 0.02, "temperature": 0.002,
                     "saturation": 0.9, "quantization": 0.01, "bias_drift": 0.05, "misalignment": 2.0,
                     "hard_iron_jump": 0.2}
DEFAULT_LSB = {"mag": 0.15e-6, "accel": G0 / 4096.0}  # SI units per count
T_REF = 25.0  # °C, temperature at which the truth calibration holds


# ----------------------------------------------------------------------------- quaternions
def _qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of (..., 4) scalar-first quaternions."""
    aw, ax, ay, az = np.moveaxis(np.asarray(a, float), -1, 0)
    bw, bx, by, bz = np.moveaxis(np.asarray(b, float), -1, 0)
    return np.stack([aw * bw - ax * bx - ay * by - az * bz,
                     aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw], axis=-1)


def _qconj(q: np.ndarray) -> np.ndarray:
    return np.asarray(q, float) * np.array([1.0, -1.0, -1.0, -1.0])


def _qexp(v: np.ndarray) -> np.ndarray:
    """Rotation vector(s) (..., 3) -> unit quaternion(s)."""
    v = np.asarray(v, float)
    ang = np.linalg.norm(v, axis=-1, keepdims=True)
    safe = np.where(ang > 1e-12, ang, 1.0)
    s = np.where(ang > 1e-12, np.sin(0.5 * ang) / safe, 0.5 - ang**2 / 48.0)
    return np.concatenate([np.cos(0.5 * ang), s * v], axis=-1)


def _qlog(q: np.ndarray) -> np.ndarray:
    """Unit quaternion(s) -> rotation vector(s) of the shortest rotation."""
    q = np.asarray(q, float)
    q = np.where(q[..., :1] < 0, -q, q)
    n = np.linalg.norm(q[..., 1:], axis=-1, keepdims=True)
    ang = 2.0 * np.arctan2(n, q[..., :1])
    return np.where(n > 1e-15, ang / np.where(n > 1e-15, n, 1.0), 2.0) * q[..., 1:]


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) (body -> world) of scalar-first quaternions (..., 4)."""
    w, x, y, z = np.moveaxis(np.asarray(q, float), -1, 0)
    r = np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
                  2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
                  2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=-1)
    return r.reshape((*w.shape, 3, 3))


def quat_from_rpy(roll, pitch, yaw) -> np.ndarray:
    """Quaternion of ZYX Euler angles in radians: R = Rz(yaw) @ Ry(pitch) @ Rx(roll)."""
    cr, sr = np.cos(0.5 * np.asarray(roll)), np.sin(0.5 * np.asarray(roll))
    cp, sp = np.cos(0.5 * np.asarray(pitch)), np.sin(0.5 * np.asarray(pitch))
    cy, sy = np.cos(0.5 * np.asarray(yaw)), np.sin(0.5 * np.asarray(yaw))
    return np.stack([cr * cp * cy + sr * sp * sy, sr * cp * cy - cr * sp * sy,
                     cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy], axis=-1)


def quat_to_rpy(q: np.ndarray) -> np.ndarray:
    """ZYX Euler angles (..., 3) = (roll, pitch, yaw) in radians."""
    r = quat_to_matrix(q)
    return np.stack([np.arctan2(r[..., 2, 1], r[..., 2, 2]), np.arcsin(np.clip(-r[..., 2, 0], -1, 1)),
                     np.arctan2(r[..., 1, 0], r[..., 0, 0])], axis=-1)


def _integrate(q0: np.ndarray, omega: np.ndarray, dt: np.ndarray) -> np.ndarray:
    """q[k+1] = q[k] ⊗ exp(omega[k] dt[k]) (body rates, zero-order hold), renormalised each step."""
    dq = _qexp(omega[:-1] * dt[:, None])
    q = np.empty((len(omega), 4))
    q[0] = q0 / np.linalg.norm(q0)
    for k in range(len(dq)):
        nxt = _qmul(q[k], dq[k])
        q[k + 1] = nxt / np.linalg.norm(nxt)
    return q


def _rates_of(q: np.ndarray, dt: np.ndarray) -> np.ndarray:
    """Body rates (rad/s) whose zero-order-hold integration reproduces the attitude track q."""
    om = np.empty((len(q), 3))
    om[:-1] = _qlog(_qmul(_qconj(q[:-1]), q[1:])) / dt[:, None]
    om[-1] = om[-2]
    return om


# ----------------------------------------------------------------------------- motion
def _smooth(rng, t, fmin, fmax, dims=3, n=6) -> np.ndarray:
    """Sum of n random sinusoids per column, roughly unit standard deviation."""
    f = rng.uniform(fmin, fmax, (n, dims))
    ph = rng.uniform(0, 2 * np.pi, (n, dims))
    a = rng.uniform(0.5, 1.0, (n, dims))
    s = np.sum(a * np.sin(2 * np.pi * f * t[:, None, None] + ph), axis=1)
    return s / np.sqrt(0.5 * np.sum(a**2, axis=0))


def _cumint(rate: np.ndarray, dt: np.ndarray) -> np.ndarray:
    """Rectangle-rule running integral of rate (N, ...) with steps dt (N-1,), starting at 0."""
    steps = rate[:-1] * dt.reshape((-1,) + (1,) * (rate.ndim - 1))
    return np.concatenate([np.zeros((1, *rate.shape[1:])), np.cumsum(steps, axis=0)])


def _random_quat(rng) -> np.ndarray:
    q = rng.normal(size=4)
    return q / np.linalg.norm(q)


def _second_order(u: np.ndarray, dt: np.ndarray, f_hz: float, zeta: float) -> np.ndarray:
    """Response of a unit-gain second-order system (natural frequency f_hz, damping zeta) to input u, semi-implicit Euler."""
    wn, y, dy = 2 * np.pi * f_hz, np.zeros(len(u)), 0.0
    for k in range(1, len(u)):
        dy += dt[k - 1] * (wn * wn * (u[k - 1] - y[k - 1]) - 2 * zeta * wn * dy)
        y[k] = y[k - 1] + dt[k - 1] * dy
    return y


def _car(t, rng, tilt_deg, mount_deg=None):
    """A car's (roll, pitch, yaw) in radians: straights and full circles (left or right), speed 6-14 m/s;
    roll from the lateral acceleration v * yaw rate through a suspension (1.2-1.6 Hz, damping 0.5-0.7,
    0.3-0.5 deg per m/s^2), pitch from the longitudinal one (braking dives the nose) through the same kind of
    suspension plus a slow road grade; road vibration; a mounting tilt (roll -4..-3 deg, pitch +-1 deg, or
    mount_deg = (roll, pitch) in degrees). The varying part is scaled down, when larger, to at most tilt_deg
    on each axis. Also the world acceleration."""
    n, dt = len(t), np.diff(t)
    rate, tc, turning = np.zeros(n), float(rng.uniform(2.0, 6.0)), True
    while tc <= t[-1]:
        if turning:
            r = rng.choice([-1.0, 1.0]) * rng.uniform(0.2, 0.45)
            dur = rng.choice([1.0, 1.0, 2.0]) * 2 * np.pi / abs(r)  # one or two full circles
        else:
            r, dur = 0.0, rng.uniform(4.0, 15.0)
        rate[(t >= tc) & (t < tc + dur)] = r
        tc, turning = tc + dur, not turning
    for k in range(1, n):  # steering lag, tau = 0.8 s
        rate[k] = rate[k - 1] + (1 - np.exp(-dt[k - 1] / 0.8)) * (rate[k] - rate[k - 1])
    speed = 10.0 + 4.0 * np.clip(_smooth(rng, t, 0.005, 0.03, dims=1)[:, 0], -1, 1) - 3.0 * np.abs(rate) / 0.45
    a_lon = np.gradient(speed, t)
    a_lat = speed * rate
    f_r, f_p = rng.uniform(1.2, 1.6, 2)
    z_r, z_p = rng.uniform(0.5, 0.7, 2)
    k_r, k_p = np.deg2rad(rng.uniform(0.3, 0.5, 2))
    roll = _second_order(k_r * a_lat, dt, f_r, z_r)  # body rolls out of the turn
    pitch = _second_order(k_p * a_lon, dt, f_p, z_p) + np.deg2rad(0.6) * _smooth(rng, t, 0.002, 0.01, dims=1)[:, 0]
    vib = np.deg2rad(0.05) * _smooth(rng, t, 2.0, 8.0, dims=2)
    var = np.c_[roll, pitch] + vib
    peak = np.max(np.abs(var), axis=0)
    var = var * np.minimum(1.0, np.deg2rad(tilt_deg) / np.maximum(peak, 1e-12))
    mount = np.deg2rad([rng.uniform(-4.0, -3.0), rng.uniform(-1.0, 1.0)])
    if mount_deg is not None:
        mount = np.deg2rad(np.asarray(mount_deg, float))
    yaw = rng.uniform(-np.pi, np.pi) + _cumint(rate, dt)
    acc = np.c_[a_lon * np.cos(yaw) - a_lat * np.sin(yaw), a_lon * np.sin(yaw) + a_lat * np.cos(yaw), np.zeros(n)]
    return var[:, 0] + mount[0], var[:, 1] + mount[1], yaw, acc


def _motion(kind, t, rng, tilt_deg, band_deg, rest_s, move_s, mount_deg=None):
    """Attitude q (N,4), body rates (N,3), world linear acceleration (N,3), still mask or None."""
    n, dt = len(t), np.diff(t)
    acc, still = np.zeros((n, 3)), None
    if kind == "tumble":
        omega = 1.2 * _smooth(rng, t, 0.02, 0.3) + rng.normal(0, 0.3, 3)
        return _integrate(_random_quat(rng), omega, dt), omega, acc, still
    if kind == "rest_and_move":
        period = rest_s + move_s
        seg = np.floor(t / period).astype(int)
        ph = (t - seg * period - rest_s) / move_s
        moving = ph > 0
        v = rng.normal(0, 1.3, (seg.max() + 1, 3))
        a = rng.normal(0, 1.5, (seg.max() + 1, 3))
        wig = 0.3 * _smooth(rng, t, 0.2, 1.0)
        env = np.where(moving, np.sin(np.pi * ph) ** 2, 0.0)
        omega = env[:, None] * (v[seg] + wig)
        # zero net velocity change per motion segment: ∫ sin(πp) sin(2πp) dp = 0
        acc = np.where(moving, np.sin(np.pi * ph) * np.sin(2 * np.pi * ph), 0.0)[:, None] * a[seg]
        return _integrate(_random_quat(rng), omega, dt), omega, acc, ~moving
    if kind == "static":
        jit = np.deg2rad(0.05) * _smooth(rng, t, 0.1, 2.0)
        att = _qmul(_random_quat(rng), _qexp(jit))
    elif kind == "ground":
        rate, tc, turning = np.zeros(n), 0.0, False
        while tc <= t[-1]:
            dur = rng.uniform(1.5, 5.0) if turning else rng.uniform(1.0, 4.0)
            r = rng.choice([-1.0, 1.0]) * rng.uniform(0.2, 0.9) if turning else 0.0
            rate[(t >= tc) & (t < tc + dur)] = r
            tc, turning = tc + dur, not turning
        for k in range(1, n):  # first-order smoothing of the steering, tau = 0.3 s
            rate[k] = rate[k - 1] + (1 - np.exp(-dt[k - 1] / 0.3)) * (rate[k] - rate[k - 1])
        yaw = rng.uniform(-np.pi, np.pi) + _cumint(rate, dt)
        rp = _smooth(rng, t, 0.05, 0.8, dims=2)
        rp = np.deg2rad(tilt_deg) * rp / np.max(np.abs(rp), axis=0)
        att = quat_from_rpy(rp[:, 0], rp[:, 1], yaw)
    elif kind == "car":
        roll, pitch, yaw, acc = _car(t, rng, tilt_deg, mount_deg)
        att = quat_from_rpy(roll, pitch, yaw)
    elif kind in ("hemisphere", "band"):
        bound = np.deg2rad(80.0 if kind == "hemisphere" else band_deg)
        theta = rng.uniform(0, 2 * np.pi, 2) + _cumint(0.3 + 0.15 * _smooth(rng, t, 0.02, 0.2, dims=2), dt)
        yaw_rate = rng.choice([-1.0, 1.0]) * 0.35 + 0.25 * _smooth(rng, t, 0.02, 0.2, dims=1)[:, 0]
        yaw = rng.uniform(-np.pi, np.pi) + _cumint(yaw_rate, dt)
        att = quat_from_rpy(bound * np.sin(theta[:, 0]), bound * np.sin(theta[:, 1]), yaw)
    else:
        raise ValueError(f"motion must be one of {MOTIONS}, got {kind!r}")
    omega = _rates_of(att, dt)
    return _integrate(att[0], omega, dt), omega, acc, still


def _unit(rng) -> np.ndarray:
    d = rng.normal(size=3)
    return d / np.linalg.norm(d)


# ----------------------------------------------------------------------------- generator
def generate(sensor="mag", motion="tumble", duration_s=60.0, rate_hz=50.0, seed=0, *,
             tilt_deg=5.0, band_deg=20.0, rest_s=1.5, move_s=2.5,
             hard_iron=None, hard_iron_mag=None, soft_iron=0.05, symmetric_soft_iron=False,
             noise=None, colored_noise=None, noise_tau_s=5.0,
             effect="none", magnitude=None, t_jump=None, unit=None, lsb=None,
             field_uT=48.0, inclination_deg=60.0, declination_deg=3.0, jitter_s=0.0,
             with_gyro=True, with_temp=False, gyro_noise=0.003, gyro_bias=0.005, gyro_scale=0.0,
             mount_deg=None, mag_mount=None, mag_mount_misalign_deg=0.0) -> dict:
    """Simulate one recording; returns {"t","xyz","gyro","temp","truth","meta"} (numpy arrays).

    sensor "mag" (field from intensity/inclination/declination, ENU) or "accel" (specific force,
    +g up when still).  hard_iron: vector in µT (mag) / m/s² (accel); default a random direction of
    norm hard_iron_mag (SI: 30e-6 T / 0.3 m/s²).  soft_iron: entries of the general matrix A in
    M = I + A, U(-soft_iron, soft_iron) (symmetrised if symmetric_soft_iron).  noise: white std in
    SI (default 0.1 µT / 0.02 m/s²); colored_noise: AR(1) std in SI (default noise/2), correlation
    time noise_tau_s.  magnitude: effect size (see module docstring; None -> DEFAULT_MAGNITUDE).
    rest_and_move: alternating still (rest_s) and moving (move_s) periods, linear acceleration when
    moving.  ground: yaw segments (turn / straight), |roll|, |pitch| <= tilt_deg.  car: straights and full
    circles, roll and pitch through a suspension (``_car``), varying by at most tilt_deg about a mounting tilt
    (mount_deg = (roll, pitch) degrees; None: drawn, roll -4..-3, pitch +-1; (0, 0): a near-level ring).  band: |roll|,
    |pitch| <= band_deg.  hemisphere: |roll|, |pitch| <= 80° (body z up).  jitter_s: time-stamp jitter.
    unit: "T" | "uT" | "counts" for mag, "m/s2" | "counts" for accel (counts: raw = round(SI / lsb)).
    gyro: body rate + constant bias N(0, gyro_bias) + white N(0, gyro_noise), rad/s; gyro_scale: per-axis
    sensitivity error U(-gyro_scale, gyro_scale) (0.03: the ±3 % tolerance of common MEMS gyros' data sheets),
    drawn after the other gyro draws so that gyro_scale=0 leaves every recording as it was.
    mag_mount: (3, 3) rotation of the magnetometer's frame against the body (IMU) frame, ``v_imu = mag_mount @
    v_mag`` (None: the same frame); mag_mount_misalign_deg: a further rotation by this angle about a random axis
    (its own generator, seeded from ``seed``: the other draws stay as they were), ``v_imu = mag_mount @
    R_small @ v_mag``. The gyro stays in the body frame; the magnetometer reads in its rotated frame. The truth
    then carries ``R_mount`` (``mag_mount @ R_small``) and ``R_to_imu``: the rotation from the frame of the
    symmetric calibration ``W_sym`` to the IMU's (``h_imu = R_to_imu @ W_sym @ (raw - offset)``).
    """
    if sensor not in ("mag", "accel"):
        raise ValueError(f"sensor must be 'mag' or 'accel', got {sensor!r}")
    if effect not in EFFECTS:
        raise ValueError(f"effect must be one of {EFFECTS}, got {effect!r}")
    unit = unit or ("T" if sensor == "mag" else "m/s2")
    units = ("T", "uT", "counts") if sensor == "mag" else ("m/s2", "SI", "T", "counts")
    if unit not in units:
        raise ValueError(f"unit for {sensor} must be one of {units}, got {unit!r}")
    m = DEFAULT_MAGNITUDE[effect] if magnitude is None else float(magnitude)
    rng = np.random.default_rng(seed)
    r_mot, r_sens, r_noise, r_eff, r_gyro, r_time = rng.spawn(6)

    n = round(duration_s * rate_hz)
    t = np.arange(n) / rate_hz
    if jitter_s > 0:
        t = t + np.clip(r_time.normal(0, jitter_s, n), -0.45 / rate_hz, 0.45 / rate_hz)
        t[0] = 0.0
    dt = np.diff(t)
    q, omega, acc, still = _motion(motion, t, r_mot, tilt_deg, band_deg, rest_s, move_s, mount_deg)
    rot = quat_to_matrix(q)

    if sensor == "mag":
        big_f = field_uT * 1e-6
        inc, dec = np.deg2rad(inclination_deg), np.deg2rad(declination_deg)
        f_world = big_f * np.array([np.cos(inc) * np.sin(dec), np.cos(inc) * np.cos(dec), -np.sin(inc)])
        world = np.broadcast_to(f_world, (n, 3))
    else:
        big_f, f_world = G0, np.array([0.0, 0.0, G0])
        world = acc + f_world
    body = np.einsum("nji,nj->ni", rot, world)  # R^T @ world
    r_mount = _mount(mag_mount, mag_mount_misalign_deg, seed)
    if r_mount is not None:
        body = body @ r_mount  # the magnetometer's frame: v_mag = r_mount^T v_imu

    si = 1e-6 if sensor == "mag" else 1.0
    if hard_iron is None:
        hm = hard_iron_mag if hard_iron_mag is not None else (30e-6 if sensor == "mag" else 0.3)
        hard = hm * _unit(r_sens)
    else:
        _unit(r_sens)  # keep the stream aligned
        hard = np.asarray(hard_iron, float) * si
    a_soft = soft_iron * r_sens.uniform(-1, 1, (3, 3))
    m_soft = np.eye(3) + (0.5 * (a_soft + a_soft.T) if symmetric_soft_iron else a_soft)
    r_mis = np.eye(3)
    offset_t = np.tile(hard, (n, 1))
    gain = np.ones((n, 3))
    params: dict = {}
    if effect == "soft_iron":
        params["delta"] = m * r_eff.uniform(-1, 1, (3, 3))
        m_soft = m_soft + params["delta"]
    elif effect == "misalignment":
        params["axis"] = _unit(r_eff)
        r_mis = quat_to_matrix(_qexp(np.deg2rad(m) * params["axis"]))
    elif effect == "bias_drift":
        rw = np.cumsum(r_eff.normal(size=(n, 3)), axis=0)
        rw -= rw[0]
        offset_t += rw * (m * big_f / max(np.max(np.linalg.norm(rw, axis=1)), 1e-300))
    elif effect == "hard_iron_jump":
        params["t_jump"] = duration_s / 2 if t_jump is None else float(t_jump)
        params["jump"] = m * big_f * _unit(r_eff)
        offset_t[t >= params["t_jump"]] += params["jump"]

    temp_true = None
    if effect == "temperature" or with_temp:
        amb_t0, amb_ramp, tau = 0.2 * duration_s, 0.1 * duration_s, 0.15 * duration_s
        amb = T_REF + 15.0 * np.clip((t - amb_t0) / amb_ramp, 0.0, 1.0)
        temp_true = np.full(n, T_REF)
        for k in range(1, n):
            temp_true[k] = temp_true[k - 1] + (1 - np.exp(-dt[k - 1] / tau)) * (amb[k - 1] - temp_true[k - 1])
        params.update(ambient_step_C=15.0, ambient_t0_s=amb_t0, ambient_ramp_s=amb_ramp, tau_s=tau)
        if effect == "temperature":
            params["offset_per_C"] = m * big_f * _unit(r_eff)
            params["gain_per_C"] = m * r_eff.uniform(-1, 1, 3)
            d_t = (temp_true - T_REF)[:, None]
            offset_t += d_t * params["offset_per_C"]
            gain += d_t * params["gain_per_C"]

    mm = m_soft @ r_mis
    sens = offset_t + gain * (body @ mm.T)

    white = (0.1e-6 if sensor == "mag" else 0.02) if noise is None else float(noise)
    colored = 0.5 * white if colored_noise is None else float(colored_noise)
    phi = np.exp(-np.concatenate([[1.0 / rate_hz], dt]) / noise_tau_s)
    innov, white_draw = r_noise.normal(size=(n, 3)), r_noise.normal(size=(n, 3))
    temp_draw = r_noise.normal(size=n)
    ar = np.empty((n, 3))
    ar[0] = colored * innov[0]
    for k in range(1, n):
        ar[k] = phi[k] * ar[k - 1] + np.sqrt(1 - phi[k] ** 2) * colored * innov[k]
    sens = sens + ar + white * white_draw

    if effect == "nonlinearity":
        params["k"] = m * r_eff.choice([-1.0, 1.0], 3) * r_eff.uniform(0.5, 1.0, 3)
        sens = sens + params["k"] * sens**3 / big_f**2
    elif effect == "saturation":
        params["limit"] = m * big_f
        sens = np.clip(sens, -params["limit"], params["limit"])
    elif effect == "quantization":
        params["lsb"] = m * big_f
        sens = np.round(sens / params["lsb"]) * params["lsb"]

    if unit == "counts":
        lsb = DEFAULT_LSB[sensor] if lsb is None else float(lsb)
        scale = 1.0 / lsb
        xyz = np.round(sens * scale)
    else:
        lsb, scale = None, (1e6 if unit == "uT" else 1.0)
        xyz = sens * scale

    w = np.linalg.inv(mm)
    _, s, vt = np.linalg.svd(w)
    truth = {"offset": offset_t[0] * scale, "M": mm, "W": w, "W_sym": vt.T @ np.diag(s) @ vt,
             "norm": big_f * scale, "field": f_world * scale, "M_soft": m_soft, "R_mis": r_mis,
             "offset_t": offset_t * scale, "q": q, "rpy_deg": np.rad2deg(quat_to_rpy(q)),
             "omega": omega, "temp": temp_true, "still": still}
    if sensor == "mag":  # best achievable by a magnitude-only (symmetric W) calibration
        truth["heading_floor_deg"] = {"level": heading_p95(truth["W_sym"], truth["offset"], truth, 0.0),
                                      "tilt30": heading_p95(truth["W_sym"], truth["offset"], truth, 30.0)}
    if r_mount is not None:
        u_w, _, vt_w = np.linalg.svd(w)
        truth["R_mount"], truth["R_to_imu"] = r_mount, r_mount @ u_w @ vt_w  # W = (U V^T) W_sym
    if effect == "hard_iron_jump":
        truth["offset_after"] = (hard + params["jump"]) * scale
    gyro = None
    bias_g = r_gyro.normal(0, gyro_bias, 3)
    gyro_draw = r_gyro.normal(0, gyro_noise, (n, 3))
    scale_g = gyro_scale * r_gyro.uniform(-1, 1, 3) if gyro_scale > 0 else np.zeros(3)
    if with_gyro:
        gyro = (1.0 + scale_g) * omega + bias_g + gyro_draw
    truth["gyro_bias"], truth["gyro_scale"] = bias_g, scale_g
    temp = None if temp_true is None else temp_true + 0.02 * temp_draw
    meta = {"sensor": sensor, "motion": motion, "duration_s": duration_s, "rate_hz": rate_hz, "seed": seed,
            "unit": unit, "lsb": lsb, "scale": scale, "effect": effect, "magnitude": m,
            "effect_params": params, "noise": {"white": white, "colored": colored, "tau_s": noise_tau_s},
            "field_uT": field_uT, "inclination_deg": inclination_deg, "declination_deg": declination_deg,
            "g": G0, "tilt_deg": tilt_deg, "band_deg": band_deg, "rest_s": rest_s, "move_s": move_s,
            "soft_iron": soft_iron, "jitter_s": jitter_s, "gyro_scale": gyro_scale,
            "mount_deg": mount_deg}
    return {"t": t, "xyz": xyz, "gyro": gyro, "temp": temp, "truth": truth, "meta": meta}


def _mount(mag_mount, misalign_deg: float, seed: int) -> np.ndarray | None:
    """The magnetometer's rotation against the body frame (``generate``'s mag_mount), None when none."""
    if mag_mount is None and not misalign_deg:
        return None
    r = np.eye(3) if mag_mount is None else np.asarray(mag_mount, float)
    if not np.allclose(r @ r.T, np.eye(3), atol=1e-9) or np.linalg.det(r) < 0:
        raise ValueError(f"mag_mount must be a proper rotation matrix, got {r.tolist()}")
    if misalign_deg:
        axis = _unit(np.random.default_rng([int(seed), 28]))
        r = r @ quat_to_matrix(_qexp(np.deg2rad(float(misalign_deg)) * axis))
    return r


def write_csv(path, rec: dict) -> None:
    """Write ``t,x,y,z`` (+ ``temp``) (+ ``gx,gy,gz``) with a one-line header, seconds and raw units."""
    names, cols = ["t", "x", "y", "z"], [rec["t"][:, None], rec["xyz"]]
    if rec.get("temp") is not None:
        names.append("temp")
        cols.append(rec["temp"][:, None])
    if rec.get("gyro") is not None:
        names += ["gx", "gy", "gz"]
        cols.append(rec["gyro"])
    np.savetxt(path, np.hstack(cols), delimiter=",", header=",".join(names), comments="", fmt="%.12g")


# ----------------------------------------------------------------------------- heading metrics
def _azimuth_error_deg(cal_body: np.ndarray, rot: np.ndarray, f_world: np.ndarray) -> np.ndarray:
    """Heading error (deg, wrapped to ±180) of tilt-compensated calibrated vectors vs the true field."""
    w = np.einsum("nij,nj->ni", rot, cal_body)
    err = np.arctan2(f_world[0], f_world[1]) - np.arctan2(w[:, 0], w[:, 1])
    return np.rad2deg((err + np.pi) % (2 * np.pi) - np.pi)


def heading_p95(W, offset, truth: dict, tilt_deg: float = 0.0, n_yaw: int = 360) -> float:
    """95th percentile of |heading error| (deg) of calibration (W, offset) on a yaw grid.

    The raw data are the noise-free truth model ``truth["offset"] + truth["M"] @ b`` (``b`` turned into the
    magnetometer's frame by ``truth["R_mount"]`` when mounted turned, ``mag_mount``); attitudes are
    level (tilt_deg=0) or all roll, pitch in {-tilt, 0, +tilt}; tilt compensation uses the true attitude.
    """
    yaw = np.arange(n_yaw) * 2 * np.pi / n_yaw
    tl = np.deg2rad(tilt_deg)
    rp = [(0.0, 0.0)] if tilt_deg == 0 else [(r, p) for r in (-tl, 0.0, tl) for p in (-tl, 0.0, tl)]
    roll = np.concatenate([np.full(n_yaw, r) for r, _ in rp])
    pitch = np.concatenate([np.full(n_yaw, p) for _, p in rp])
    rot = quat_to_matrix(quat_from_rpy(roll, pitch, np.tile(yaw, len(rp))))
    f = np.asarray(truth["field"], float)
    body = np.einsum("nji,j->ni", rot, f)
    if "R_mount" in truth:  # a magnetometer mounted turned (generate's mag_mount): W must give the IMU's frame
        body = body @ truth["R_mount"]
    raw = truth["offset"] + body @ np.asarray(truth["M"]).T
    cal = (raw - np.asarray(offset, float)) @ np.asarray(W, float).T
    return float(np.percentile(np.abs(_azimuth_error_deg(cal, rot, f)), 95))


def heading_error_deg(W, offset, rec: dict) -> dict:
    """Heading error of (W, offset) on a recording, tilt-compensated with the TRUE attitude.

    Returns {"err_deg": per-sample signed error, "p95": p95 of |err|, "level_p95": heading_p95 at
    level attitudes, "tilt30_p95": heading_p95 at ±30° tilts} (the last two noise-free, truth model).
    """
    if rec["meta"]["sensor"] != "mag":
        raise ValueError("heading error is only defined for magnetometer recordings")
    tr = rec["truth"]
    cal = (np.asarray(rec["xyz"], float) - np.asarray(offset, float)) @ np.asarray(W, float).T
    err = _azimuth_error_deg(cal, quat_to_matrix(tr["q"]), np.asarray(tr["field"], float))
    return {"err_deg": err, "p95": float(np.percentile(np.abs(err), 95)),
            "level_p95": heading_p95(W, offset, tr, 0.0), "tilt30_p95": heading_p95(W, offset, tr, 30.0)}
