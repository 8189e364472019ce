"""Quality of a flight log's inputs for strapdown estimation: data that parses but cannot give a trustworthy
estimate (docs/estimators.md, 'Inputs the estimators refuse').

:func:`assess_input_quality` returns one :class:`QualityFinding` per problem, each graded ``"refuse"`` (the
estimators refuse the log unless told to replay it anyway) or ``"flag"`` (the estimate is made, and carries the
finding as a warning). Checked:

* **IMU rate** (``imu_rate``): the median rate of the ``imu`` stream; below :data:`IMU_REFUSE_RATE_HZ` refused,
  below :data:`IMU_FLAG_RATE_HZ` flagged.
* **IMU gaps** (``imu_gaps``): intervals longer than 5 median periods (and 0.1 s); the longest and the fraction of
  the flight they cover.
* **Accelerometer clipping** (``accel_clipping``): flat runs at an axis' extreme, where the extreme is beyond any
  accelerometer's smallest range (2 g).
* **GPS without a 3D fix** (``gps_no_fix``): a ``gps`` stream none of whose rows has a 3D fix.
* **Time base** (``time_base``): stream times that step back, jump forward by more than :data:`TIME_JUMP_S`, or lie
  that far outside the IMU span.

Everything here is a pure function of the data: the refusal policy (what a refused finding stops, and the
override) is :func:`estimators.api.run_estimators`'.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ingest.flightlog import FlightLog

#: Severity of a finding the estimators refuse (unless overridden) and of one they only report.
REFUSE, FLAG = "refuse", "flag"
SEVERITIES = (REFUSE, FLAG)

#: IMU rates [Hz]: below the first the strapdown integration is refused, below the second flagged
#: (docs/estimators.md, 'Inputs the estimators refuse').
IMU_REFUSE_RATE_HZ = 50.0
IMU_FLAG_RATE_HZ = 100.0
#: Angular rate [deg/s] of a brisk UAV manoeuvre, used to state the rotation per IMU interval in the messages.
MANOEUVRE_RATE_DEG_S = 100.0

#: An IMU interval is a gap above this many median periods and above :data:`GAP_MIN_S` (as ``stream_info``).
GAP_FACTOR = 5.0
GAP_MIN_S = 0.1
#: Longest IMU gap [s] flagged / refused.
IMU_GAP_FLAG_S = 0.5
IMU_GAP_REFUSE_S = 5.0
#: Fraction of the IMU span inside gaps flagged / refused.
IMU_GAP_FRACTION_FLAG = 0.05
IMU_GAP_FRACTION_REFUSE = 0.20

#: Standard gravity [m/s^2] (g units in the messages).
STANDARD_GRAVITY_M_S2 = 9.80665
#: An extreme below this [m/s^2] (2 g, the smallest range of a MEMS accelerometer) cannot be a clipping rail.
CLIP_MIN_EXTREME_M_S2 = 2.0 * STANDARD_GRAVITY_M_S2
#: Samples within this fraction of an axis' extreme are near it.
CLIP_BAND = 0.01
#: ... and flat when consecutive ones differ by at most this fraction of the extreme.
CLIP_FLAT_TOLERANCE = 1e-5
#: A clipping run holds at least this many consecutive flat samples near the extreme.
CLIP_MIN_RUN = 3
#: Fraction of IMU samples clipped above which the log is refused.
CLIP_REFUSE_FRACTION = 0.01
ACCEL_COLUMNS = ("accel_x_m_s2", "accel_y_m_s2", "accel_z_m_s2")

#: Minimum PX4 ``fix_type`` of a 3D fix.
GPS_3D_FIX = 3
#: A stream time step [s] above this (or any step back) is a jump of the time base.
TIME_JUMP_S = 60.0


@dataclass(frozen=True)
class QualityFinding:
    """One problem with a log's inputs.

    Attributes
    ----------
    kind : str
        ``"imu_rate"``, ``"imu_gaps"``, ``"accel_clipping"``, ``"gps_no_fix"`` or ``"time_base"``.
    severity : str
        ``"refuse"`` or ``"flag"`` (:data:`SEVERITIES`).
    stream : str
        Canonical stream concerned (``"imu"``, ``"gps"`` ...).
    message : str
        One line naming the stream, its source topic and the figure, and what it does to the estimate.
    value : float
        The figure checked, in ``unit``.
    threshold : float
        The limit it crossed (the refusal limit for a refused finding, else the flag limit), in ``unit``.
    unit : str
        Unit of ``value`` and ``threshold`` (``"Hz"``, ``"s"``, ``"fraction"``, ``"rows"``).
    """

    kind: str
    severity: str
    stream: str
    message: str
    value: float
    threshold: float
    unit: str


def assess_input_quality(flight_log: FlightLog) -> tuple[QualityFinding, ...]:
    """Every quality finding of ``flight_log``, refused ones first (see the module docstring).

    A missing stream gives no finding here: the reader reports missing sensors, the estimators' sensor plan
    what follows from them.
    """
    findings: list[QualityFinding] = []
    topics = {name: info.topic for name, info in flight_log.meta.streams.items()}
    if flight_log.has("imu"):
        imu = flight_log["imu"]
        time_s = imu.index.to_numpy(dtype=float)
        label = _label("imu", topics)
        findings += imu_rate_findings(time_s, label)
        findings += imu_gap_findings(time_s, label)
        columns = [c for c in ACCEL_COLUMNS if c in imu.columns]
        findings += clipping_findings(imu[columns].to_numpy(dtype=float), columns, label)
    if flight_log.has("gps"):
        findings += gps_fix_findings(flight_log["gps"], _label("gps", topics))
    findings += time_base_findings({name: frame.index.to_numpy(dtype=float)
                                    for name, frame in flight_log.streams.items() if len(frame)}, topics)
    return tuple(sorted(findings, key=lambda f: SEVERITIES.index(f.severity)))


def _label(stream: str, topics: dict[str, str]) -> str:
    return f"{stream} ({topics[stream]})" if stream in topics else stream


def _median_period_s(time_s: np.ndarray) -> float:
    dt = np.diff(time_s)
    dt = dt[dt > 0]
    return float(np.median(dt)) if len(dt) else float("nan")


def imu_rate_findings(time_s: np.ndarray, label: str = "imu") -> list[QualityFinding]:
    """The IMU rate finding, if any, for sample times ``time_s`` [s].

    Below :data:`IMU_REFUSE_RATE_HZ` refused, below :data:`IMU_FLAG_RATE_HZ` flagged; the message gives the
    rotation between samples at :data:`MANOEUVRE_RATE_DEG_S`.
    """
    period_s = _median_period_s(np.asarray(time_s, dtype=float))
    if not np.isfinite(period_s):
        return []
    rate_hz = 1.0 / period_s
    step_deg = MANOEUVRE_RATE_DEG_S * period_s
    if rate_hz < IMU_REFUSE_RATE_HZ:
        return [QualityFinding(
            "imu_rate", REFUSE, "imu",
            f"{label} logged at {rate_hz:.1f} Hz, below the {IMU_REFUSE_RATE_HZ:g} Hz strapdown integration needs "
            f"(a {MANOEUVRE_RATE_DEG_S:g} deg/s manoeuvre turns {step_deg:.1f} deg between samples)",
            rate_hz, IMU_REFUSE_RATE_HZ, "Hz")]
    if rate_hz < IMU_FLAG_RATE_HZ:
        return [QualityFinding(
            "imu_rate", FLAG, "imu",
            f"{label} logged at {rate_hz:.1f} Hz, below the {IMU_FLAG_RATE_HZ:g} Hz of PX4 EKF2's prediction: "
            f"coarse attitude integration ({step_deg:.1f} deg between samples at {MANOEUVRE_RATE_DEG_S:g} deg/s)",
            rate_hz, IMU_FLAG_RATE_HZ, "Hz")]
    return []


def imu_gap_findings(time_s: np.ndarray, label: str = "imu") -> list[QualityFinding]:
    """The IMU gap finding, if any, for sample times ``time_s`` [s] (gaps as in ``ingest.flightlog.stream_info``).

    Refused when the longest gap exceeds :data:`IMU_GAP_REFUSE_S` or the gaps cover more than
    :data:`IMU_GAP_FRACTION_REFUSE` of the span; flagged above :data:`IMU_GAP_FLAG_S` or
    :data:`IMU_GAP_FRACTION_FLAG`.
    """
    time_s = np.asarray(time_s, dtype=float)
    period_s = _median_period_s(time_s)
    span_s = float(time_s[-1] - time_s[0]) if len(time_s) > 1 else 0.0
    if not np.isfinite(period_s) or span_s <= 0:
        return []
    dt = np.diff(time_s)
    is_gap = dt > max(GAP_FACTOR * period_s, GAP_MIN_S)
    if not is_gap.any():
        return []
    k = int(np.argmax(np.where(is_gap, dt, -np.inf)))
    longest_s, fraction = float(dt[k]), float(dt[is_gap].sum() / span_s)
    figures = (f"{label}: {int(is_gap.sum())} gaps, longest {longest_s:.2f} s at {time_s[k]:.3f} s, "
               f"{100 * fraction:.1f} % of the flight without IMU data")
    for severity, limit_s, limit_fraction, consequence in (
            (REFUSE, IMU_GAP_REFUSE_S, IMU_GAP_FRACTION_REFUSE,
             f"(limits {IMU_GAP_REFUSE_S:g} s, {100 * IMU_GAP_FRACTION_REFUSE:g} %): the filter would dead-reckon "
             "across them on held rates"),
            (FLAG, IMU_GAP_FLAG_S, IMU_GAP_FRACTION_FLAG,
             f"(flagged above {IMU_GAP_FLAG_S:g} s or {100 * IMU_GAP_FRACTION_FLAG:g} %): propagated across on "
             "held rates")):
        if longest_s > limit_s or fraction > limit_fraction:
            by_length = longest_s > limit_s
            return [QualityFinding("imu_gaps", severity, "imu", f"{figures} {consequence}",
                                   longest_s if by_length else fraction, limit_s if by_length else limit_fraction,
                                   "s" if by_length else "fraction")]
    return []


def clipped_samples(values: np.ndarray) -> np.ndarray:
    """Mask of the samples of one accelerometer axis ``values`` [m/s^2] that sit on a clipping rail.

    Each sign is checked on its own: a rail is the extreme ``e`` (max or min, ``|e|`` at least
    :data:`CLIP_MIN_EXTREME_M_S2`), and a sample is on it when it lies within :data:`CLIP_BAND` of ``e`` in a run
    of at least :data:`CLIP_MIN_RUN` consecutive samples that differ by at most :data:`CLIP_FLAT_TOLERANCE`
    ``|e|`` (a saturated sensor repeats its limit; a manoeuvre's peak varies from sample to sample).
    """
    values = np.asarray(values, dtype=float)
    clipped = np.zeros(len(values), dtype=bool)
    finite = values[np.isfinite(values)]
    if len(values) < CLIP_MIN_RUN or not len(finite):
        return clipped
    for extreme in (float(finite.max()), float(finite.min())):
        if abs(extreme) < CLIP_MIN_EXTREME_M_S2:
            continue
        near = np.abs(values - extreme) <= CLIP_BAND * abs(extreme)
        flat = near[1:] & near[:-1] & (np.abs(np.diff(values)) <= CLIP_FLAT_TOLERANCE * abs(extreme))
        # runs of consecutive flat pairs: a run of m pairs holds m + 1 samples
        edges = np.diff(np.concatenate(([0], flat.astype(np.int8), [0])))
        for start, stop in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True):
            if stop - start + 1 >= CLIP_MIN_RUN:
                clipped[start:stop + 1] = True
    return clipped


def clipping_findings(accel_m_s2: np.ndarray, columns, label: str = "imu") -> list[QualityFinding]:
    """The accelerometer clipping finding, if any, for specific forces ``accel_m_s2`` (n, k) [m/s^2] whose
    columns are named ``columns``.

    Flagged when any sample is on a rail (:func:`clipped_samples`); refused when more than
    :data:`CLIP_REFUSE_FRACTION` of the rows have an axis on one.
    """
    accel_m_s2 = np.asarray(accel_m_s2, dtype=float).reshape(len(accel_m_s2), -1)
    masks = [clipped_samples(accel_m_s2[:, j]) for j in range(accel_m_s2.shape[1])]
    if not masks or not any(mask.any() for mask in masks):
        return []
    rows = np.logical_or.reduce(masks)
    fraction = float(rows.sum() / len(rows))
    axes = ", ".join(f"{column.split('_')[1]} at {accel_m_s2[mask, j][0]:+.1f} m/s^2 "
                     f"({accel_m_s2[mask, j][0] / STANDARD_GRAVITY_M_S2:+.1f} g, {int(mask.sum())} samples)"
                     for j, (column, mask) in enumerate(zip(columns, masks, strict=True)) if mask.any())
    message = (f"{label}: accelerometer clipping, flat at the range limit on axis {axes}: {int(rows.sum())} "
               f"samples, {100 * fraction:.2f} % of the flight; the specific force beyond the range is lost")
    if fraction > CLIP_REFUSE_FRACTION:
        return [QualityFinding("accel_clipping", REFUSE, "imu",
                               f"{message} (refused above {100 * CLIP_REFUSE_FRACTION:g} %)", fraction,
                               CLIP_REFUSE_FRACTION, "fraction")]
    return [QualityFinding("accel_clipping", FLAG, "imu", message, fraction, 0.0, "fraction")]


def gps_fix_findings(gps, label: str = "gps") -> list[QualityFinding]:
    """The finding of a ``gps`` stream (DataFrame with ``fix_type``, ``lat_deg``, ``lon_deg``) none of whose rows
    has a 3D fix (``fix_type >= 3``, finite position, not at latitude/longitude (0, 0)): flagged."""
    if not len(gps):
        return []
    fix = gps["fix_type"].to_numpy(dtype=float) if "fix_type" in gps.columns else np.full(len(gps), np.nan)
    lat, lon = (gps[c].to_numpy(dtype=float) if c in gps.columns else np.full(len(gps), np.nan)
                for c in ("lat_deg", "lon_deg"))
    fixed = (fix >= GPS_3D_FIX) & np.isfinite(lat) & np.isfinite(lon) & ~((lat == 0) & (lon == 0))
    if fixed.any():
        return []
    best = f"best fix type {int(np.nanmax(fix))}" if np.isfinite(fix).any() else "no fix type"
    return [QualityFinding(
        "gps_no_fix", FLAG, "gps",
        f"{label}: no 3D fix in any of its {len(gps)} rows ({best}): no position or velocity aiding, so the "
        "estimates carry attitude and height only (position, velocity and wind NaN)",
        0.0, float(GPS_3D_FIX), "rows")]


def time_base_findings(times_s: dict[str, np.ndarray], topics: dict[str, str] | None = None) -> list[QualityFinding]:
    """Jumps of the time base visible in stream times ``times_s`` (stream -> times [s]): steps back, steps forward
    longer than :data:`TIME_JUMP_S`, and streams starting or ending that far outside the ``imu`` span. Flagged
    (one finding per stream)."""
    topics = topics or {}
    findings = []
    imu = times_s.get("imu")
    span = (float(np.min(imu)), float(np.max(imu))) if imu is not None and len(imu) else None
    for stream, time_s in times_s.items():
        time_s = np.asarray(time_s, dtype=float)
        problems, worst_s, limit_s = [], 0.0, 0.0
        dt = np.diff(time_s)
        if (dt < 0).any():
            problems.append(f"{int((dt < 0).sum())} steps back (largest {-dt.min():.3f} s)")
            worst_s = max(worst_s, float(-dt.min()))
        if (dt > TIME_JUMP_S).any():
            k = int(np.argmax(dt))
            problems.append(f"{int((dt > TIME_JUMP_S).sum())} jumps forward over {TIME_JUMP_S:g} s "
                            f"(largest {dt[k]:.1f} s at {time_s[k]:.3f} s)")
            worst_s, limit_s = max(worst_s, float(dt[k])), TIME_JUMP_S
        if span is not None and stream != "imu" and len(time_s):
            outside_s = max(span[0] - float(np.min(time_s)), float(np.max(time_s)) - span[1])
            if outside_s > TIME_JUMP_S:
                problems.append(f"times {float(np.min(time_s)):.1f} .. {float(np.max(time_s)):.1f} s reach "
                                f"{outside_s:.1f} s outside the IMU span {span[0]:.1f} .. {span[1]:.1f} s")
                worst_s, limit_s = max(worst_s, outside_s), TIME_JUMP_S
        if problems:
            findings.append(QualityFinding(
                "time_base", FLAG, stream,
                f"{_label(stream, topics)}: the time base jumps: {'; '.join(problems)}; samples across a jump are "
                "placed on the wrong time", worst_s, limit_s, "s"))
    return findings
