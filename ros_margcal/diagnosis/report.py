"""The diagnosis written out: ``diagnosis.json`` for scripts, ``report.html`` (PNG plots embedded as
base64, one self-contained file) for people, and a short console summary.

The two files change together: both are rendered in memory (plots included) before anything is
written, then written to temporary files beside their targets, and renamed over them one after the
other with Ctrl-C held back (``_replace_together``). An interrupt or a failure leaves the previous
run's pair, never a new ``diagnosis.json`` beside an old ``report.html``.
"""

from __future__ import annotations

import base64
import contextlib
import html
import io
import json
import logging
import math
import os
import signal
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from ..model.calibration_file import write_temp
from ..model.errors import ConfigError
from .core import Diagnosis
from .ranking import EffectFit
from .twin import FIT_ERRORS

__all__ = ["figure_png", "summary", "write_report"]

log = logging.getLogger(__name__)

WARM_UP_NAME = "warm-up drift"
"""How ``temperature`` is printed on a recording without a temperature column."""
WARM_UP_KELVIN = 15.0
"""Temperature rise of the warm-up the simulator synthesises without a temperature column (25 -> 40 °C)."""


def _plt() -> Any:
    import matplotlib  # optional dependency (plots only): imported when a plot is asked for

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def figure_png(fig: Any) -> bytes:
    """The figure as PNG bytes (the figure is closed)."""
    plt = _plt()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    plt.close(fig)
    return buf.getvalue()


def _sphere_map(diag: Diagnosis) -> bytes:
    plt = _plt()
    twin = diag.twin
    assert twin is not None
    feats = [twin.features_rec]
    titles = ["recording"]
    if twin._cache:
        feats.append(twin.features(None, 0))
        titles.append("baseline twin (seed 0)")
    fig = plt.figure(figsize=(11, 3.8))
    lim = float(np.quantile(np.abs(feats[0].residual), 0.98)) or 1e-9
    for i, (f, title) in enumerate(zip(feats, titles, strict=True)):
        ax = fig.add_subplot(1, len(feats), i + 1, projection="mollweide")
        lon = np.arctan2(f.dirs[:, 1], f.dirs[:, 0])
        lat = np.arcsin(np.clip(f.dirs[:, 2], -1, 1))
        sc = ax.scatter(lon, lat, c=f.residual, s=3, cmap="coolwarm", vmin=-lim, vmax=lim)
        ax.set_title(f"{title}: relative norm residual over direction", fontsize=9)
        ax.grid(True, alpha=0.3)
        fig.colorbar(sc, ax=ax, orientation="horizontal", fraction=0.05, pad=0.08)
    return figure_png(fig)


def _time_plot(diag: Diagnosis) -> bytes:
    plt = _plt()
    twin = diag.twin
    assert twin is not None
    fig, ax = plt.subplots(figsize=(11, 3.2))
    rec = twin.features_rec
    ax.plot(rec.t, rec.residual, ".", ms=1.5, label="recording")
    base = twin.features(None, 0)
    ax.plot(base.t, base.residual, ".", ms=1.5, alpha=0.6, label="baseline twin")
    best = diag.best
    if best is not None and diag.cause != "none":
        eff = twin.features({best.name: best.magnitude}, 0)
        ax.plot(eff.t, eff.residual, ".", ms=1.5, alpha=0.6, label=f"twin + {best.name}")
    if twin.temp is not None:
        ax2 = ax.twinx()
        ax2.plot(twin.t, twin.temp, "k-", lw=0.8, alpha=0.5)
        ax2.set_ylabel("temperature, °C")
    ax.set_xlabel("time, s")
    ax.set_ylabel("|W(v-b)|/n - 1 (diag fit)")
    ax.legend(loc="upper right", fontsize=8, markerscale=6)
    return figure_png(fig)


def _gap_plot(diag: Diagnosis) -> bytes:
    plt = _plt()
    names = list(diag.stages_before)
    x = np.arange(len(names))
    fig, ax = plt.subplots(figsize=(11, 3.2))
    ax.bar(x - 0.2, [diag.stages_before[n] for n in names], 0.4, label="baseline twin")
    ax.bar(x + 0.2, [diag.stages_after.get(n, 0.0) for n in names], 0.4, label=f"twin + {diag.cause}")
    ax.axhline(2.5, color="k", lw=0.8, ls="--", label="within the baseline's spread below this")
    ax.set_xticks(x, names, rotation=20, fontsize=8)
    ax.set_ylabel("stage gap (RMS z)")
    ax.set_yscale("symlog", linthresh=1.0)
    ax.legend(fontsize=8)
    return figure_png(fig)


def _img(png: bytes, alt: str) -> str:
    return f'<img alt="{html.escape(alt)}" src="data:image/png;base64,{base64.b64encode(png).decode()}"/>'


def _table(rows: list[list[str]], head: list[str]) -> str:
    out = ["<table><tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in head) + "</tr>"]
    out += ["<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in r) + "</tr>" for r in rows]
    return "\n".join(out) + "</table>"


def _json_safe(x: Any) -> Any:
    if isinstance(x, dict):
        return {str(k): _json_safe(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_json_safe(v) for v in x]
    if isinstance(x, np.generic):
        x = x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def summary(diag: Diagnosis) -> str:
    """A few lines for the console."""
    lines = [f"where: {diag.where} (stage gap {diag.stages_before.get(diag.where, 0.0):.1f}; overall {diag.gap_before:.2f},"
             f" baseline's own {max(diag.null_gaps, default=0.0):.2f})"]
    best = diag.best
    if diag.cause == "none":
        lines.append("cause: none (the recording is within the baseline's own spread)")
    elif best is None or diag.reason:
        lines.append(f"cause: {diag.cause} ({diag.reason or 'no effect could be fitted'})")
    else:
        members = [_shown(n, diag.has_temperature) for n in diag.cause_effects]
        also = f" ({' / '.join(members)}: cannot be told apart)" if len(members) > 1 else ""
        lines.append(f"cause: {diag.cause}{also}; {_fitted(best, diag.has_temperature)}")
        lines.append(f"shrink: {100 * diag.shrink:.0f} % of the gap removed "
                     f"(overall {diag.gap_before:.2f} -> {diag.gap_after:.2f})")
    if diag.close_calls():
        lines.append(f"close call (the data barely separate them): {', '.join(diag.close_calls())}")
    lines += _ranking_lines(diag)
    if diag.unobservable:
        lines.append(f"unobservable with norm-based data: {', '.join(diag.unobservable)}")
    for name, why in diag.skipped.items():
        lines.append(f"stage {name} skipped: {why}")
    if diag.time_restarts:
        k = len(diag.time_restarts)
        lines.append(f"time: the clock goes back (or jumps ahead by more than a day) {k} time{'s' if k > 1 else ''} "
                     f"(first after sample {diag.time_restarts[0]}: a logger restart?); the samples are taken in file "
                     "order, the times after each step continued from the part before")
    oc = diag.offset_change
    if oc:
        lines.append(f"offset change at t \u2248 {oc['t']:.1f} s (step {100 * oc['relative_step']:.0f} % of the field "
                     "radius): no single calibration fits the recording; the twin is the fit of the side with more motion")
    ds = diag.downstream
    if ds.get("available") and "predicted_control" in ds:
        lines.append(f"validator on a {ds['n_points']}-sample set: measured error {ds['measured']:.3g}, "
                     f"predicted {ds['predicted_before']:.3g} (log error {ds['log_error_before']:.2f}); "
                     f"retrained on {ds['n_sets']} sets with {ds['effect']}: {ds['predicted_after']:.3g} "
                     f"({ds['log_error_after']:.2f}); on {ds['n_sets']} sets without it: {ds['predicted_control']:.3g} "
                     f"({ds['log_error_control']:.2f})")
    return "\n".join(lines)


def _shown(name: str, has_temperature: bool) -> str:
    """An effect's name as printed: without a temperature column ``temperature`` is only a drift of the shape
    of a warm-up (``ranking.effective_group``), so it is not called temperature."""
    return WARM_UP_NAME if name == "temperature" and not has_temperature else name


def _fitted(best: EffectFit, has_temperature: bool) -> str:
    """The named effect and its fitted size; a temperature effect without a temperature column as the offset
    drift its synthesised warm-up (``WARM_UP_KELVIN``) makes, not as a coefficient per kelvin."""
    if best.name == "temperature" and not has_temperature:
        return f"{WARM_UP_NAME}: the offset drifts by about {_drift_percent(best)} over the recording along a warm-up curve"
    return f"{best.name} at {best.magnitude:.4g} {best.unit}"


def _drift_percent(f: EffectFit) -> str:
    """The offset change a temperature effect's synthesised warm-up makes, in % of the field."""
    return f"{100 * f.magnitude * WARM_UP_KELVIN:.3g} % of the field"


def _size(f: EffectFit, has_temperature: bool) -> str:
    """An effect's fitted magnitude with its unit (a warm-up drift as its offset change, ``_fitted``)."""
    if f.name == "temperature" and not has_temperature:
        return f"{_drift_percent(f)} (offset drift)"
    return f"{f.magnitude:.4g} {f.unit}"


def _ranking_lines(diag: Diagnosis) -> list[str]:
    """The ranking in shrink order (largest first); a line more when the named effect is not the first of it
    (decided on what separates the two, ``ranking.separate_close_calls`` / ``separate_step_from_walk``)."""
    by_shrink = sorted(diag.effects, key=lambda f: (-f.shrink, f.gap_after))
    out = ["ranking (share of the gap removed): "
           + ", ".join(f"{_shown(f.name, diag.has_temperature)} {100 * f.shrink:.0f} %" for f in by_shrink[:4])]
    best = diag.best
    if best is not None and by_shrink and by_shrink[0] is not best and diag.cause not in ("none", "unexplained"):
        out.append(f"named {_shown(best.name, diag.has_temperature)} before "
                   f"{_shown(by_shrink[0].name, diag.has_temperature)} ({100 * best.shrink:.1f} % against "
                   f"{100 * by_shrink[0].shrink:.1f} %): the features that separate the two, or the time course of "
                   "the offset, fit it better")
    return out


@contextlib.contextmanager
def _interrupts_held() -> Iterator[None]:
    """Hold Ctrl-C (SIGINT) back for the block and deliver it right after (main thread; elsewhere a no-op).

    A Python-level handler records the signal: blocking it with a signal mask would not do, since the
    process's other threads (OpenBLAS's) would take it and Python would raise in the main thread anyway.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[int] = []
    try:
        previous = signal.signal(signal.SIGINT, lambda signum, frame: caught.append(signum))
    except (ValueError, OSError):  # no signals here (an embedding interpreter)
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous)
        if caught:
            signal.raise_signal(signal.SIGINT)  # as if it came now: KeyboardInterrupt under Python's own handler


def _replace_together(contents: dict[Path, str]) -> None:
    """Write every ``{path: text}`` to a temporary file, then rename them all over their targets.

    Nothing is renamed until every temporary file is written; the renames run with Ctrl-C held back
    (``_interrupts_held``), so an interrupt leaves all old files or all new ones. Temporary files are
    removed on any failure.
    """
    temps: dict[Path, Path] = {}
    try:
        for path, text in contents.items():
            temps[path] = write_temp(path, text)
        with _interrupts_held():
            for path, tmp in temps.items():
                os.replace(tmp, path)
    except BaseException:
        for tmp in temps.values():
            with contextlib.suppress(OSError):
                tmp.unlink()
        raise


def write_report(diag: Diagnosis, out_dir: str | Path, *, extra: dict[str, Any] | None = None,
                 plots: bool = True) -> tuple[Path, Path]:
    """Write ``diagnosis.json`` and ``report.html`` into ``out_dir`` (created); returns both paths. Without
    ``plots`` the report has its tables only and matplotlib is not imported (its import and the three figures are
    several seconds of a quick diagnosis).

    Both are rendered first and replace the previous pair together (``_replace_together``): an
    interrupt (Ctrl-C) or an error while rendering or writing leaves the previous files as they were.
    """
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        msg = f"cannot create the output directory {out}: {exc}"
        raise ConfigError(msg) from exc
    data = diag.to_dict()
    if extra:
        data.update(extra)
    jpath = out / "diagnosis.json"
    json_text = json.dumps(_json_safe(data), indent=2)
    figs = []
    if diag.twin is not None and plots:
        try:
            figs = [_img(_sphere_map(diag), "residual over direction"), _img(_time_plot(diag), "residual over time"),
                    _img(_gap_plot(diag), "stage gaps before and after")]
        except FIT_ERRORS as exc:  # the report is written without its plots rather than not at all
            log.warning("report plots left out: %s", exc)
    eff_rows = [[_shown(f.name, diag.has_temperature), f.group, _size(f, diag.has_temperature), f"{f.gap_before:.2f}",
                 f"{f.gap_after:.2f}", f"{100 * f.shrink:.0f} %"]
                for f in sorted(diag.effects, key=lambda f: (-f.shrink, f.gap_after))]
    stage_rows = [[k, f"{v:.2f}", f"{diag.stages_after.get(k, v):.2f}"] for k, v in diag.stages_before.items()]
    groups = "; ".join(f"{g['group']}: {', '.join(g['effects'])}" for g in diag.equivalent) or "none"  # type: ignore[arg-type]
    body = f"""<!doctype html><html><head><meta charset="utf-8"><title>margcal diagnosis</title>
<style>body{{font-family:sans-serif;max-width:1100px;margin:auto}}table{{border-collapse:collapse}}
td,th{{border:1px solid #ccc;padding:2px 8px;font-size:13px}}img{{max-width:100%}}</style></head><body>
<h1>Sim-to-real gap diagnosis</h1>
<pre>{html.escape(summary(diag))}</pre>
<p>Sensor {html.escape(diag.sensor)}, {diag.n_samples} samples ({diag.n_fit} in the fitting stages), rest noise
{diag.noise:.3g} of the field radius, {diag.seconds:.1f} s. Gaps are RMS z-scores against the baseline twin's
spread over seeds. Equivalent (cannot be told apart): {html.escape(groups)}. Unobservable:
{html.escape(', '.join(diag.unobservable) or 'none')}.</p>
<h2>Where: stage gaps</h2>{_table(stage_rows, ["stage", "gap (baseline twin)", "gap (twin + cause)"])}
{figs[2] if figs else ""}
<h2>Which: effects ranked by the share of the gap they remove</h2>
{_table(eff_rows, ["effect", "group", "fitted magnitude", "gap before", "gap after", "shrink"])}
<h2>Residual over direction</h2>{figs[0] if figs else ""}
<h2>Residual over time</h2>{figs[1] if figs else ""}
<h2>Downstream: the validator</h2><pre>{html.escape(json.dumps(_json_safe(diag.downstream), indent=1))}</pre>
{"<h2>Withheld part</h2><pre>" + html.escape(json.dumps(_json_safe(extra), indent=1)) + "</pre>" if extra else ""}
</body></html>"""
    hpath = out / "report.html"
    _replace_together({jpath: json_text, hpath: body})
    log.debug("wrote %s and %s", jpath, hpath)  # the command prints it (with the times): once on the console
    return jpath, hpath
