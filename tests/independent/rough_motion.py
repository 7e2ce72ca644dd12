"""Rough motion for the independent generator: attitude steps of a few degrees between samples.

``generate_rough`` wraps ``generator.generate`` without changing it and without the package: the
recording is generated ``speedup`` times longer at a ``speedup`` times lower rate and its clock divided
by ``speedup`` (a platform that turns ``speedup`` times faster, the same samples), then, for a vibrating
platform, the rows are shuffled within consecutive blocks of ``shuffle`` samples (the times stay in
order: the attitude jumps back and forth between neighbouring samples). Effects whose time course is set
in seconds (``t_jump``, the coloured noise's correlation time) are scaled with the clock.
"""

from __future__ import annotations

import numpy as np


def step_deg(q: np.ndarray) -> np.ndarray:
    """Angles (degrees) of the attitude change between consecutive scalar-first unit quaternions (n, 4)."""
    dots = np.abs(np.einsum("ij,ij->i", q[:-1], q[1:]))
    return np.rad2deg(2.0 * np.arccos(np.clip(dots, -1.0, 1.0)))


def _shuffle_rows(n: int, block: int, rng: np.random.Generator) -> np.ndarray:
    """Row order that permutes each consecutive block of ``block`` indices at random (identity for block < 2)."""
    order = np.arange(n)
    if block < 2:
        return order
    for start in range(0, n, block):
        order[start:start + block] = rng.permutation(order[start:start + block])
    return order


def generate_rough(gen, sensor: str = "mag", motion: str = "tumble", duration_s: float = 60.0, rate_hz: float = 50.0,
                   seed: int = 0, *, speedup: float = 3.0, shuffle: int = 2, **kwargs) -> dict:
    """``gen.generate(...)`` with the motion ``speedup`` times faster and rows shuffled in blocks of ``shuffle``.

    ``gen`` is the loaded ``tests/independent/generator.py`` module. Returns the generator's dict with
    ``t`` relabelled, ``xyz``, ``gyro``, ``temp`` and the per-sample truth (``q``, ``offset_t``, ``omega``,
    ``temp``, ``still``) in the new row order, ``meta["rough"] = {"speedup", "shuffle", "median_step_deg"}``.
    """
    if speedup <= 0:
        raise ValueError(f"speedup must be positive, got {speedup!r}")
    if kwargs.get("t_jump") is not None:
        kwargs["t_jump"] = float(kwargs["t_jump"]) * speedup
    kwargs["noise_tau_s"] = float(kwargs.get("noise_tau_s", 5.0)) * speedup  # the same correlation time in seconds
    rec = gen.generate(sensor, motion, duration_s * speedup, rate_hz / speedup, seed, **kwargs)
    n = rec["t"].size
    order = _shuffle_rows(n, int(shuffle), np.random.default_rng([int(seed), 7919]))
    out = dict(rec)
    out["t"] = rec["t"] / speedup
    for key in ("xyz", "gyro", "temp"):
        if rec.get(key) is not None:
            out[key] = rec[key][order]
    truth = dict(rec["truth"])
    for key in ("q", "offset_t", "temp", "still", "rpy_deg"):
        if truth.get(key) is not None:
            truth[key] = truth[key][order]
    if truth.get("omega") is not None:
        truth["omega"] = truth["omega"][order] * speedup
    out["truth"] = truth
    meta = dict(rec["meta"])
    meta.update(duration_s=duration_s, rate_hz=rate_hz, rough={"speedup": speedup, "shuffle": int(shuffle),
                                                               "median_step_deg": float(np.median(step_deg(truth["q"])))})
    if "t_jump" in meta.get("effect_params", {}):
        meta["effect_params"] = {**meta["effect_params"], "t_jump": meta["effect_params"]["t_jump"] / speedup}
    out["meta"] = meta
    return out
