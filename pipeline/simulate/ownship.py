"""`ownship` scenario: a ship with a corrected gyrocompass, a GNSS receiver and an
induction log (gyro/GNSS/log paper, "Дослідження динамічних похибок ІСКК").

The paper's scenario (eq. 5-6): speed through water V = 0.05 t m/s up to 9 m/s at 180 s,
then steady; a full 240-s turn from minute 15 to 19; irregular roll with correlation
D e^{-mu|tau|}(cos nu tau + mu/nu sin nu|tau|), D = 0.12 rad^2, nu = 0.6 rad/s,
mu = 0.01 1/s; the gyro z = 3 m above the centre of mass. The gyro's error dynamics are
OUR plain model (``pipeline.filters.gyro_gnss_log``, module docstring): the same linear
equations the filter uses, integrated here at a fine step with the TRUE accelerations
(deterministic speed-up and turn, not the filter's Gauss-Markov W).

Sensors (1 Hz by default):

- GNSS: position error Gauss-Markov, latitude sigma 2.9e-5 deg (the paper's receiver)
  and the same in metres east, correlation ``gnss_position_tau_s``; velocity error
  Gauss-Markov per axis with sigma 0.053 m/s and correlation 15 s, so that the change
  of speed over 1 s has sigma ~0.019 m/s^2, the paper's figure for the differentiated
  speed; outlier fixes (position and velocity jumps, still fix quality 1) and outages
  (fix quality 0) at configured times; position jumps (``jumps``: the positions of a
  time span moved by a fixed offset, the velocity not: spoofing, multipath), whose truth
  goes with the outages' to the ``/truth/faults`` channel (table ``fault_truth``).
- gyrocompass: heading K + alpha (HDT, resolution ``heading_resolution_deg``), the
  accelerometer signal (mean of beta + a_N/g over each sample interval) and the
  amplifier output delta, with white noise.
- induction log: speed through water + constant bias + white noise (sigma 0.5 m/s).
- water current: constant vector; ground velocity = V (sin K, cos K) + current.

Everything is a pure function of (config, start, duration, seed). ``write_ownship_archive``
writes the result as MCAP: NMEA 0183 text channels (GGA, RMC, VTG / HDT / VHW, message
encoding ``nmea0183``, channel metadata ``platform_id``), a JSON channel of gyro signals
(``surveil.GyroSignals``) and the truth (``surveil.OwnshipTruth``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import numpy as np
import polars as pl

from pipeline import frames
from pipeline.filters import kalman
from pipeline.filters.gyro_gnss_log import EARTH_RATE_RADPS, G_MPS2, GyroModel, RollModel
from pipeline.io.mcap_write import write_mcap_file
from pipeline.messages import message_layout
from pipeline.nav.config import OwnshipScenarioConfig
from pipeline.simulate.channel_faults import FAULT_TRUTH_SCHEMA
from pipeline.units import KNOT_MPS, NS

GYRO_SIGNALS_SCHEMA = "surveil.GyroSignals"
OWNSHIP_TRUTH_SCHEMA = "surveil.OwnshipTruth"
FAULT_TRUTH_SCHEMA_NAME = "surveil.FaultTruth"
MCAP_LIBRARY = "surveil-pipeline/ownship"


@dataclass(frozen=True)
class OwnshipScenario:
    """Simulated samples (int64 ns times, SI units)."""

    start_ns: int
    duration_s: float
    seed: int
    platform_id: str
    truth: pl.DataFrame  # per sample: lat/lon, heading, gyro error, speeds, W, roll
    gyro_signals: pl.DataFrame  # time_ns, accel_signal_rad, amplifier_rad
    gyro_heading: pl.DataFrame  # time_ns, heading_rad (K + alpha, quantised)
    gnss: pl.DataFrame  # time_ns, lat_deg, lon_deg, sog_mps, cog_rad, fix_quality, is_outlier
    speed_log: pl.DataFrame  # time_ns, speed_water_mps
    fault_truth: pl.DataFrame  # the GNSS outages and jumps (FAULT_TRUTH_SCHEMA)


def kinematics(t_s: np.ndarray, c: OwnshipScenarioConfig) -> dict[str, np.ndarray]:
    """Paper eq. 5 and the full turn: speed through water V, its rate W, heading K, turn
    rate K-dot and the centripetal acceleration a_s = V K-dot (to starboard), SI units."""
    t_full = c.max_speed_mps / c.accel_mps2
    V = np.minimum(c.accel_mps2 * t_s, c.max_speed_mps)
    W = np.where(t_s < t_full, c.accel_mps2, 0.0)
    rate = c.turn_direction * 2.0 * np.pi / c.turn_duration_s
    in_turn = (t_s >= c.turn_start_s) & (t_s < c.turn_start_s + c.turn_duration_s)
    K = c.initial_heading_rad + rate * np.clip(t_s - c.turn_start_s, 0.0, c.turn_duration_s)
    K_dot = np.where(in_turn, rate, 0.0)
    return {"V": V, "W": W, "K": np.mod(K, 2 * np.pi), "K_dot": K_dot, "a_s": V * K_dot}


def _gauss_markov(
    rng: np.random.Generator, n: int, dt: float, sigma: float, tau: float, dims: int = 1
) -> np.ndarray:
    """Stationary first-order Gauss-Markov samples (n, dims): x_k = a x_{k-1} + w."""
    a = math.exp(-dt / tau)
    w = rng.normal(0.0, sigma * math.sqrt(1.0 - a * a), (n, dims))
    w[0] = rng.normal(0.0, sigma, dims)
    from scipy.signal import lfilter

    return lfilter([1.0], [1.0, -a], w, axis=0)


def _gyro_and_roll(
    rng: np.random.Generator,
    kin: dict[str, np.ndarray],
    h: float,
    lat_rad: float,
    gyro: GyroModel,
    roll: RollModel,
    alpha0: float,
) -> np.ndarray:
    """States (alpha, beta, delta, phi, phi-dot) at every fine step (n + 1, 5).

    The continuous model of ``pipeline.filters.gyro_gnss_log`` (roll shaping filter of
    eq. 6 driving the accelerometer through z phi-ddot sin K) with the TRUE acceleration
    W and centripetal a_s as inputs, discretised exactly per fine step (Van Loan, the
    heading of the middle of the step), so that the joint noise of roll and gyro is
    exact in distribution whatever the step. ``kin``: kinematics at the middle of each
    fine step.
    """
    from pipeline.filters.gyro_gnss_log import NavFilterModel, continuous_model

    model = NavFilterModel(gyro=gyro, roll=roll)
    n = kin["K"].size
    # the model depends on the heading only: discretise each distinct heading once
    K, which = np.unique(kin["K"], return_inverse=True)
    A6, G6, B6 = continuous_model(np.full(K.size, lat_rad), K, model)
    five = slice(0, 5)
    A = A6[:, five, five]
    G = G6[:, five, :3]  # xi_alpha, xi_beta, xi_phi (W is an input here)
    B = np.concatenate([A6[:, five, 5:6], B6[:, five, :]], axis=2)  # inputs W, a_s
    F, Q, Gamma = kalman.discretize(A, G, h, B)
    L = np.linalg.cholesky(Q + 1e-30 * np.eye(5))
    F, L, Gamma = F[which], L[which], Gamma[which]
    w = np.einsum("nij,nj->ni", L, rng.standard_normal((n, 5)))
    drive = np.einsum("nij,nj->ni", Gamma, np.column_stack([kin["W"], kin["a_s"]])) + w
    d0 = EARTH_RATE_RADPS * math.cos(lat_rad) * alpha0 / gyro.tilt_damping_per_s
    x = np.empty((n + 1, 5))
    # start at rest with alpha0 held still (delta = Omega_H alpha0 / k_b, beta = delta),
    # roll from its stationary distribution
    x[0] = [
        alpha0,
        d0,
        d0,
        *(
            rng.normal(0.0, 1.0, 2)
            * np.sqrt([roll.variance_rad2, roll.variance_rad2 * roll.omega0_sq])
        ),
    ]
    for j in range(n):  # fine time steps of a recursive process
        x[j + 1] = F[j] @ x[j] + drive[j]
    return x


def simulate_ownship(
    c: OwnshipScenarioConfig, *, start_ns: int, duration_s: float, seed: int
) -> OwnshipScenario:
    """Simulate ``duration_s`` seconds of the scenario from ``start_ns``."""
    rng = np.random.default_rng(seed)
    h = c.truth_step_s
    per = round(c.sample_period_s / h)
    n_samples = int(duration_s // c.sample_period_s)
    n = n_samples * per
    t = np.arange(n + 1) * h
    kin = kinematics(t, c)
    mid = kinematics(t[:-1] + 0.5 * h, c)
    lat0 = math.radians(c.start_lat_deg)
    alpha0 = rng.normal(0.0, c.initial_gyro_error_sigma_rad)
    st = _gyro_and_roll(rng, mid, h, lat0, c.gyro, c.roll, alpha0)
    gyro, roll = st[:, :3], st[:, 3:]
    roll_acc = np.diff(roll[:, 1]) / h  # mean roll acceleration over each fine step
    sK = np.sin(mid["K"])
    a_north = mid["W"] * np.cos(mid["K"]) + c.gyro.mount_height_m * roll_acc * sK - mid["a_s"] * sK
    # accelerometer signal per fine step: mean tilt (trapezoid) + mean a_N / g
    acc_sig_fine = 0.5 * (gyro[:-1, 1] + gyro[1:, 1]) + a_north / G_MPS2

    cur = c.current_speed_mps * np.array([math.sin(c.current_set_rad), math.cos(c.current_set_rad)])
    vg = np.column_stack([mid["V"] * np.sin(mid["K"]), mid["V"] * np.cos(mid["K"])]) + cur
    pos = np.vstack([[0.0, 0.0], np.cumsum(vg * h, axis=0)])  # ENU at the fine step

    k = np.arange(1, n_samples + 1) * per  # fine index of each sample (end of interval)
    ts = t[k]
    time_ns = start_ns + np.round(ts * NS).astype(np.int64)
    lat, lon = frames.enu_to_geodetic(pos[k, 0], pos[k, 1], c.start_lat_deg, c.start_lon_deg)
    vg_s = (
        np.column_stack([kin["V"][k] * np.sin(kin["K"][k]), kin["V"][k] * np.cos(kin["K"][k])])
        + cur
    )
    truth = pl.DataFrame(
        {
            "time_ns": time_ns,
            "platform_id": c.platform_id,
            "lat_deg": lat,
            "lon_deg": lon,
            "heading_rad": kin["K"][k],
            "gyro_error_rad": gyro[k, 0],
            "tilt_rad": gyro[k, 1],
            "speed_water_mps": kin["V"][k],
            "sog_mps": np.hypot(vg_s[:, 0], vg_s[:, 1]),
            "cog_rad": np.mod(np.arctan2(vg_s[:, 0], vg_s[:, 1]), 2 * np.pi),
            "accel_mps2": kin["W"][k],
            "roll_rad": roll[k, 0],
            "current_east_mps": cur[0],
            "current_north_mps": cur[1],
        }
    )
    acc_mean = acc_sig_fine.reshape(n_samples, per).mean(axis=1)
    gyro_signals = pl.DataFrame(
        {
            "time_ns": time_ns,
            "accel_signal_rad": acc_mean + rng.normal(0, c.accelerometer_sigma_rad, n_samples),
            "amplifier_rad": gyro[k, 2] + rng.normal(0, c.amplifier_sigma_rad, n_samples),
        }
    )
    res = math.radians(c.heading_resolution_deg)
    gyro_heading = pl.DataFrame(
        {
            "time_ns": time_ns,
            "heading_rad": np.mod(np.round((kin["K"][k] + gyro[k, 0]) / res) * res, 2 * np.pi),
        }
    )
    gnss = _gnss(rng, c, ts, time_ns, pos[k], vg_s)
    speed_log = pl.DataFrame(
        {
            "time_ns": time_ns,
            "speed_water_mps": kin["V"][k]
            + c.log_bias_mps
            + rng.normal(0.0, c.log_sigma_mps, n_samples),
        }
    )
    return OwnshipScenario(
        start_ns,
        float(duration_s),
        seed,
        c.platform_id,
        truth,
        gyro_signals,
        gyro_heading,
        gnss,
        speed_log,
        gnss_fault_truth(c, start_ns, duration_s),
    )


def gnss_fault_truth(c: OwnshipScenarioConfig, start_ns: int, duration_s: float
                     ) -> pl.DataFrame:
    """One ``fault_truth`` row per GNSS outage (fix quality 0) and position jump of the
    scenario that starts before its end."""
    rows = []
    for kind, spans in (("gnss_outage", [(a, b, None) for a, b in c.outages_s]),
                        ("gnss_jump", [(a, b, (e, n)) for a, b, e, n in c.jumps])):
        for a, b, off in spans:
            if a >= duration_s:
                continue
            rows.append({
                "start_ns": start_ns + round(a * NS),
                "end_ns": start_ns + round(min(a + b, duration_s) * NS),
                "family": "nav", "sensor_kind": "gnss", "channel": c.platform_id,
                "kind": kind, "value": None if off is None else math.hypot(*off),
                "unit": None if off is None else "m", "vessel_id": None, "mmsi": None,
                "detail": None if off is None else f"east {off[0]:.1f} m, north {off[1]:.1f} m",
            })
    return pl.DataFrame(rows, schema=FAULT_TRUTH_SCHEMA, orient="row") if rows else \
        pl.DataFrame(schema=FAULT_TRUTH_SCHEMA)


def _gnss(
    rng: np.random.Generator,
    c: OwnshipScenarioConfig,
    ts: np.ndarray,
    time_ns: np.ndarray,
    pos: np.ndarray,
    vel: np.ndarray,
) -> pl.DataFrame:
    """GNSS fixes: Gauss-Markov position/velocity errors, outliers, outages (quality 0)."""
    n = ts.size
    dt = c.sample_period_s
    sigma_pos_m = math.radians(c.gnss_lat_sigma_deg) * 6_371_000.0
    pos_err = _gauss_markov(rng, n, dt, sigma_pos_m, c.gnss_position_tau_s, 2)
    vel_err = _gauss_markov(rng, n, dt, c.gnss_speed_sigma_mps, c.gnss_velocity_tau_s, 2)
    outage = np.zeros(n, bool)
    for start, length in c.outages_s:
        outage |= (ts > start) & (ts <= start + length)
    jump = np.zeros((n, 2))
    for start, length, east, north in c.jumps:
        jump[(ts > start) & (ts <= start + length)] += (east, north)
    outlier = np.zeros(n, bool)
    candidates = np.flatnonzero(~outage & (ts > 60.0))
    # keep outliers apart from outages and from each other (>= 10 s)
    near = np.zeros(n, bool)
    for start, length in c.outages_s:
        near |= (ts > start - 10.0) & (ts <= start + length + 10.0)
    candidates = candidates[~near[candidates]]
    picked: list[int] = []
    for i in rng.permutation(candidates):  # a handful of draws, not per message
        if len(picked) == c.outlier_count:
            break
        if all(abs(i - j) >= 10 for j in picked):
            picked.append(int(i))
    outlier[picked] = True
    m = len(picked)
    ang = rng.uniform(0, 2 * np.pi, (m, 2))
    dp = rng.uniform(*c.outlier_position_m, m)
    dv = rng.uniform(*c.outlier_velocity_mps, m)
    pos_err[picked] += np.column_stack([dp * np.sin(ang[:, 0]), dp * np.cos(ang[:, 0])])
    vel_err[picked] += np.column_stack([dv * np.sin(ang[:, 1]), dv * np.cos(ang[:, 1])])
    p = pos + pos_err + jump
    v = vel + vel_err
    lat, lon = frames.enu_to_geodetic(p[:, 0], p[:, 1], c.start_lat_deg, c.start_lon_deg)
    return pl.DataFrame(
        {
            "time_ns": time_ns,
            "lat_deg": np.where(outage, np.nan, lat),
            "lon_deg": np.where(outage, np.nan, lon),
            "sog_mps": np.where(outage, np.nan, np.hypot(v[:, 0], v[:, 1])),
            "cog_rad": np.where(outage, np.nan, np.mod(np.arctan2(v[:, 0], v[:, 1]), 2 * np.pi)),
            "fix_quality": np.where(outage, 0, 1).astype(np.int16),
            "is_outlier": outlier,
        }
    ).with_columns(pl.col(["lat_deg", "lon_deg", "sog_mps", "cog_rad"]).fill_nan(None))


# -- NMEA 0183 sentences ---------------------------------------------------------------
# Built as polars string columns (fixed-point fields from integer arithmetic), checksums
# by one numpy XOR-reduce over the padded bytes: no Python per sentence.


def _fixed(expr: pl.Expr, decimals: int, int_width: int = 1) -> pl.Expr:
    """Non-negative number -> ``int.frac`` with ``decimals`` digits, zero-padded int part."""
    scale = 10**decimals
    scaled = (expr * scale).round(0).cast(pl.Int64)
    whole = (scaled // scale).cast(pl.String).str.zfill(int_width)
    return whole + pl.lit(".") + (scaled % scale).cast(pl.String).str.zfill(decimals)


def _angle_dm(expr: pl.Expr, deg_width: int) -> pl.Expr:
    """|angle| in deg -> NMEA ``d..dmm.mmmmm`` (5 decimals of minutes, ~2 cm)."""
    total = (expr.abs() * 60.0 * 1e5).round(0).cast(pl.Int64)
    deg = (total // 6_000_000).cast(pl.String).str.zfill(deg_width)
    minutes = total % 6_000_000
    return (deg + (minutes // 100_000).cast(pl.String).str.zfill(2) + pl.lit(".")
            + (minutes % 100_000).cast(pl.String).str.zfill(5))


def _utc_fields(time_ns: pl.Expr) -> tuple[pl.Expr, pl.Expr]:
    """``hhmmss.ss`` and ``ddmmyy`` of an int64 ns UTC column."""
    t = time_ns.cast(pl.Datetime("ns"))
    cs = ((time_ns % NS) // 10_000_000).cast(pl.String).str.zfill(2)
    return t.dt.strftime("%H%M%S") + pl.lit(".") + cs, t.dt.strftime("%d%m%y")


def nmea_checksums(bodies: pl.Series) -> np.ndarray:
    """XOR of the characters of each sentence body (between ``$`` and ``*``), uint8."""
    raw = bodies.cast(pl.Binary).to_numpy().astype(bytes)
    width = max(1, raw.dtype.itemsize)
    codes = np.frombuffer(raw.astype(f"S{width}").tobytes(), np.uint8).reshape(-1, width)
    return np.bitwise_xor.reduce(codes, axis=1)  # zero padding does not change a XOR


def finish_sentences(bodies: pl.Series) -> pl.Series:
    """``$`` + body + ``*hh`` (upper-case hex checksum)."""
    table = pl.Series([f"{v:02X}" for v in range(256)])  # 256 hex codes, once
    hexes = table.gather(nmea_checksums(bodies).astype(np.int64))
    return ("$" + bodies + "*" + hexes).alias(bodies.name)


def gnss_sentences(gnss: pl.DataFrame, talker: str = "GP") -> pl.DataFrame:
    """GGA + RMC (+ VTG with a fix) per epoch: ``time_ns``, ``sentence`` (with checksum).

    Outage epochs (fix quality 0): GGA with quality 0 and empty position, RMC with
    status V; no VTG (the receiver has nothing to say)."""
    hms, dmy = _utc_fields(pl.col("time_ns"))
    fix = pl.col("fix_quality") > 0
    lat = _angle_dm(pl.col("lat_deg"), 2) + "," + pl.when(pl.col("lat_deg") >= 0).then(
        pl.lit("N")).otherwise(pl.lit("S"))
    lon = _angle_dm(pl.col("lon_deg"), 3) + "," + pl.when(pl.col("lon_deg") >= 0).then(
        pl.lit("E")).otherwise(pl.lit("W"))
    kn = pl.col("sog_mps") / KNOT_MPS
    cog = _fixed(pl.col("cog_rad") * (180.0 / math.pi), 2)
    gga = pl.when(fix).then(
        pl.lit(f"{talker}GGA,") + hms + "," + lat + "," + lon
        + ",1,10,0.9,5.0,M,30.0,M,,"
    ).otherwise(pl.lit(f"{talker}GGA,") + hms + ",,,,,0,00,99.9,,M,,M,,")
    rmc = pl.when(fix).then(
        pl.lit(f"{talker}RMC,") + hms + ",A," + lat + "," + lon + "," + _fixed(kn, 3) + ","
        + cog + "," + dmy + ",,,A"
    ).otherwise(pl.lit(f"{talker}RMC,") + hms + ",V,,,,,,," + dmy + ",,,N")
    vtg = pl.lit(f"{talker}VTG,") + cog + ",T,,M," + _fixed(kn, 3) + ",N," \
        + _fixed(pl.col("sog_mps") * 3.6, 3) + ",K,A"
    rows = gnss.select(
        "time_ns", gga.alias("gga"), rmc.alias("rmc"), pl.when(fix).then(vtg).alias("vtg"))
    long = rows.unpivot(["gga", "rmc", "vtg"], index="time_ns", variable_name="kind",
                        value_name="body").drop_nulls("body")
    order = pl.col("kind").replace_strict({"gga": 0, "rmc": 1, "vtg": 2}, return_dtype=pl.Int8)
    long = long.with_columns(order.alias("k")).sort(["time_ns", "k"], maintain_order=True)
    return long.select("time_ns", finish_sentences(long["body"]).alias("sentence"))


def hdt_sentences(heading: pl.DataFrame, talker: str = "HE") -> pl.DataFrame:
    """``$HEHDT,hhh.hh,T`` per sample (gyro heading, true)."""
    body = pl.lit(f"{talker}HDT,") + _fixed(pl.col("heading_rad") * (180.0 / math.pi), 2) \
        + ",T"
    rows = heading.select("time_ns", body.alias("body"))
    return rows.select("time_ns", finish_sentences(rows["body"]).alias("sentence"))


def vhw_sentences(log: pl.DataFrame, talker: str = "VW") -> pl.DataFrame:
    """``$VWVHW,,T,,M,x.xx,N,x.xx,K`` per sample (speed through water, no heading)."""
    v = pl.col("speed_water_mps").clip(lower_bound=0.0)
    body = pl.lit(f"{talker}VHW,,T,,M,") + _fixed(v / KNOT_MPS, 2) + ",N," \
        + _fixed(v * 3.6, 2) + ",K"
    rows = log.select("time_ns", body.alias("body"))
    return rows.select("time_ns", finish_sentences(rows["body"]).alias("sentence"))


# -- MCAP archive ------------------------------------------------------------------------

TOPIC_GNSS = "/ownship/gnss/nmea"
TOPIC_GYRO_NMEA = "/ownship/gyro/nmea"
TOPIC_LOG = "/ownship/log/nmea"
TOPIC_GYRO_SIGNALS = "/ownship/gyro/signals"
TOPIC_TRUTH = "/ownship/truth"
TOPIC_FAULTS = "/truth/faults"


def _json_payloads(df: pl.DataFrame, fields: list[str]) -> pl.Series:
    return df.select(
        pl.struct([pl.col(f) for f in fields]).struct.json_encode().cast(pl.Binary).alias("p")
    )["p"]


def _schema(file_name: str) -> tuple[bytes, list[str]]:
    """The schema's bytes (the channel's MCAP schema) and its fields in order."""
    layout = message_layout(file_name)
    return layout.data, layout.names


def ownship_messages(sc: OwnshipScenario, sample_period_s: float) -> pl.DataFrame:
    """Every message of the scenario: ``log_time_ns``, ``channel`` (index into
    :data:`CHANNELS`), ``payload`` (bytes), in log-time order (ties: channel, row)."""
    _, gyro_fields = _schema("gyro_signals.schema.json")
    _, truth_fields = _schema("ownship_truth.schema.json")
    pid = pl.lit(sc.platform_id)
    gyro = sc.gyro_signals.with_columns(pid.alias("platform_id"),
                                        pl.lit(float(sample_period_s)).alias("interval_s"))
    truth = sc.truth.with_columns(pid.alias("platform_id"))
    parts = [
        (gnss_sentences(sc.gnss), 0),
        (hdt_sentences(sc.gyro_heading), 1),
        (vhw_sentences(sc.speed_log), 2),
    ]
    frames = [pl.DataFrame({"log_time_ns": df["time_ns"], "channel": ch,
                            "payload": df["sentence"].cast(pl.Binary)}) for df, ch in parts]
    frames.append(pl.DataFrame({"log_time_ns": gyro["time_ns"], "channel": 3,
                                "payload": _json_payloads(gyro, gyro_fields)}))
    frames.append(pl.DataFrame({"log_time_ns": truth["time_ns"], "channel": 4,
                                "payload": _json_payloads(truth, truth_fields)}))
    _, fault_fields = _schema("fault_truth.schema.json")
    frames.append(pl.DataFrame({"log_time_ns": sc.fault_truth["start_ns"], "channel": 5,
                                "payload": _json_payloads(sc.fault_truth, fault_fields)},
                               schema={"log_time_ns": pl.Int64, "channel": pl.Int32,
                                       "payload": pl.Binary}))
    return (pl.concat([f.with_columns(pl.col("channel").cast(pl.Int32),
                                      pl.int_range(pl.len(), dtype=pl.Int64).alias("row"))
                       for f in frames])
            .sort(["log_time_ns", "channel", "row"]).drop("row"))


CHANNELS = (  # (topic, message encoding, schema name or None)
    (TOPIC_GNSS, "nmea0183", None),
    (TOPIC_GYRO_NMEA, "nmea0183", None),
    (TOPIC_LOG, "nmea0183", None),
    (TOPIC_GYRO_SIGNALS, "json", GYRO_SIGNALS_SCHEMA),
    (TOPIC_TRUTH, "json", OWNSHIP_TRUTH_SCHEMA),
    (TOPIC_FAULTS, "json", FAULT_TRUTH_SCHEMA_NAME),
)


def write_ownship_archive(sc: OwnshipScenario, out_dir: Path, *, sample_period_s: float,
                          file_period_s: float = 3600.0) -> list[Path]:
    """Write the scenario as zstd MCAP files (one per ``file_period_s`` of log time, named
    ``ownship_<YYYYMMDDTHHMMSSZ>.mcap``); every channel carries the metadata
    ``platform_id``. Bytes depend only on the inputs; temp file + ``os.replace``."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    period_ns = round(file_period_s * NS)
    schemas = {GYRO_SIGNALS_SCHEMA: _schema("gyro_signals.schema.json")[0],
               OWNSHIP_TRUTH_SCHEMA: _schema("ownship_truth.schema.json")[0],
               FAULT_TRUTH_SCHEMA_NAME: _schema("fault_truth.schema.json")[0]}
    messages = ownship_messages(sc, sample_period_s).with_columns(
        (pl.col("log_time_ns") // period_ns).alias("file_index"))
    meta = {"name": "ownship", "site": "ownship", "seed": str(sc.seed),
            "start_ns": str(sc.start_ns), "duration_s": repr(float(sc.duration_s)),
            "platform_id": sc.platform_id}
    paths = []
    for (file_index,), df in messages.group_by(["file_index"], maintain_order=True):
        start = int(file_index) * period_ns
        stamp = datetime.fromtimestamp(start // NS, tz=UTC).strftime("%Y%m%dT%H%M%SZ")
        path = out_dir / f"ownship_{stamp}.mcap"
        _write_mcap(path, schemas, {**meta, "file_start_ns": str(start),
                                    "file_end_ns": str(start + period_ns)}, sc.platform_id, df)
        paths.append(path)
    return paths


def _write_mcap(path: Path, schemas: dict[str, bytes], metadata: dict[str, str],
                platform_id: str, df: pl.DataFrame) -> None:
    channels = [(*ch, {"platform_id": platform_id}) for ch in CHANNELS]
    write_mcap_file(path, channels, schemas, metadata, df, library=MCAP_LIBRARY)


def simulate_ownship_archive(cfg, start_ns: int, duration_s: float, seed: int,
                             out_dir: Path) -> list[Path]:
    """``surveil simulate --scenario ownship``: the scenario of ``[ownship.scenario]``
    (``jobs.simulate.SCENARIOS`` signature) as hourly MCAP files."""
    from pipeline.nav.config import ownship_config

    oc = ownship_config(cfg)
    sc = simulate_ownship(oc.scenario, start_ns=start_ns, duration_s=duration_s, seed=seed)
    return write_ownship_archive(sc, out_dir, sample_period_s=oc.scenario.sample_period_s)
