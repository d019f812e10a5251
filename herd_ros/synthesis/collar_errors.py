"""What GPS collars deliver: a true herd trajectory turned into noisy, gappy, irregular fixes.

:func:`simulate_collar_fixes` samples each collar on its own clock (nominal interval, a random
phase per collar, timing jitter), evaluates the true position there (linear interpolation of
the :class:`~herd_ros.trajectory.HerdTrajectory`), adds the errors below and converts ENU to
WGS84 with :func:`herd_ros.ingest.geodesy.enu_to_geodetic` (exact, about the datum).

Error model (per collar, per axis; defaults in :class:`CollarErrorModel`, typical of
consumer-grade GNSS collars):

* **Correlated noise**: a first-order Gauss-Markov process (stationary std σ_gm = 2.2 m,
  correlation time τ = 120 s), ``x_k = φ x_{k-1} + σ_gm √(1-φ²) ξ_k``, ``φ = exp(-Δt/τ)``,
  plus white noise (σ_w = 1.2 m): about 2.5 m per horizontal axis. Vertical: 4 m + 2 m.
  Both are scaled by a slowly varying HDOP-like factor h (log-normal, median 1, log-std 0.25,
  τ = 600 s), which the collar also reports: ``cov_ee = cov_nn = h² (σ_gm² + σ_w²)``.
* **Multipath jumps**: episodes of 1-3 consecutive fixes offset by 20-80 m in a random
  direction, ~1 % of fixes; the reported covariance does not show them (flag ``multipath``).
* **Dropouts**: outages starting at a rate of one per 40 min, each 30-180 s long, plus single
  skipped fixes (1 %): about 5 % of the nominal fixes are missing.
* **Irregular intervals**: per-collar phase, jitter N(0, 30 ms) (clipped at ±0.3 interval),
  stamps rounded to 1 ms; together with the skips and outages the intervals are irregular.
* **NO_FIX**: 0.3 % of the remaining fixes carry ``status = -1`` with a position 50-300 m off
  the truth, NaN altitude and unknown covariance — they must be rejected by status alone.
* **NaN altitude**: 1 % of the valid fixes have no vertical solution (allowed by NavSatFix).

Real-collar faults (off by default; :meth:`CollarErrorModel.real_collar` turns them all on
with the figures seen on deployed cattle and wildlife collars):

* **Duty cycle** (``fix_interval_range``): each interval drawn uniformly in a range (e.g.
  30-250 s) instead of a fixed rate — collars that save battery, or schedule fixes by
  activity.
* **Silences** (``silence_rate``, ``silence_duration``): hours to days without a fix (the
  collar lost its sky view under a tree line, its battery sagged overnight, or its
  store-and-forward radio failed), then it comes back.
* **Late start / early end** (``late_start_fraction``, ``early_end_fraction``): collars put on
  after the others, or that die before the end of the deployment.
* **Outlier bursts** (``burst_rate``, ``burst_fixes``, ``burst_offset``): runs of 3-10
  consecutive fixes hundreds of metres to kilometres off, clustered about one wrong place
  (``burst_scatter`` of the offset) — bad satellite geometry or a cold start computing
  a wrong solution for a while; the reported covariance does not show them (flag ``burst``).
* **Duplicated stamps** (``duplicate_probability``): a fix delivered twice with the same
  stamp (store-and-forward retransmission; flag ``duplicate``).

The returned table follows the fixes table of :mod:`herd_ros.io.gps_files` (so
``herd_ros.io.bags.write_fix_bag`` and the ingest pipeline take it as is), plus truth and
diagnostic columns:

=========================== ======================================================
``time``                    fix time, seconds (same clock as the trajectory), float
``agent``                   collar / animal id
``lat``, ``lon``            WGS84 degrees
``alt``                     metres above the ellipsoid (datum altitude + up error); NaN
                            when the fix has no vertical solution
``status``                  NavSatStatus.status: 0 = STATUS_FIX, -1 = STATUS_NO_FIX
``position_covariance_type`` 1 = COVARIANCE_TYPE_APPROXIMATED (0 = UNKNOWN on NO_FIX rows)
``cov_ee, cov_en, cov_nn``  reported east/north covariance (m²); cov_en = 0; NaN on NO_FIX
``cov_uu``                  reported vertical variance (m²); NaN on NO_FIX rows
``true_x, true_y``          the true ENU position at ``time`` (m), for evaluation only
``multipath``               True if the fix carries a multipath jump
``burst``                   True if the fix belongs to an outlier burst
``duplicate``               True for the second copy of a duplicated fix
=========================== ======================================================

Rows are sorted by time (then agent order). Deterministic for a seed.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.signal import lfilter

from herd_ros.errors import HerdInputError
from herd_ros.trajectory import HerdTrajectory

#: NavSatStatus.status values.
STATUS_FIX, STATUS_NO_FIX = 0, -1
#: NavSatFix.position_covariance_type values used here.
COVARIANCE_TYPE_UNKNOWN, COVARIANCE_TYPE_APPROXIMATED = 0, 1
#: Datum used when the trajectory carries none (the example of doc/formats.md).
DEFAULT_DATUM = (27.0153, -108.7937, 0.0)

GPS_CSV_COLUMNS = ('time', 'agent', 'lat', 'lon', 'alt')


@dataclass(frozen=True)
class CollarErrorModel:
    """Parameters of the collar error model (units: s, m; probabilities per fix)."""

    fix_interval: float = 1.0             # s, nominal time between fixes
    timing_jitter_std: float = 0.03       # s, std of the stamp jitter (clipped at ±0.3 interval)
    horizontal_gm_std: float = 2.2        # m, stationary std of the Gauss-Markov error per axis
    horizontal_white_std: float = 1.2     # m, white noise per axis
    vertical_gm_std: float = 4.0          # m
    vertical_white_std: float = 2.0       # m
    gm_tau: float = 120.0                 # s, correlation time of the Gauss-Markov error
    hdop_log_std: float = 0.25            # std of log of the HDOP-like scale factor
    hdop_tau: float = 600.0               # s, its correlation time
    multipath_fraction: float = 0.01      # expected fraction of fixes with a jump
    multipath_max_fixes: int = 3          # an episode lasts 1..this many fixes
    multipath_offset: tuple = (20.0, 80.0)  # m, size of the jump
    skip_probability: float = 0.01        # single skipped fixes
    outage_rate: float = 1.0 / 2400.0     # 1/s, rate at which outages start
    outage_duration: tuple = (30.0, 180.0)  # s
    no_fix_probability: float = 0.003     # fixes delivered with status NO_FIX
    no_fix_offset: tuple = (50.0, 300.0)  # m, how wrong a NO_FIX position is
    nan_alt_probability: float = 0.01     # valid fixes without altitude
    # --- real-collar faults (off by default) -----------------------------------------------
    fix_interval_range: tuple | None = None   # s, duty-cycled intervals U(lo, hi)
    silence_rate: float = 0.0             # 1/s, rate at which silences start
    silence_duration: tuple = (6 * 3600.0, 30 * 3600.0)  # s
    late_start_fraction: float = 0.0      # share of collars that start late
    late_start: tuple = (3600.0, 12 * 3600.0)  # s after the start of the trajectory
    early_end_fraction: float = 0.0       # share of collars that end early
    early_end: tuple = (3600.0, 12 * 3600.0)   # s before the end of the trajectory
    burst_rate: float = 0.0               # probability per fix that a burst starts
    burst_fixes: tuple = (3, 10)          # fixes per burst
    burst_offset: tuple = (300.0, 3000.0)  # m, distance of the wrong place
    burst_scatter: float = 0.1            # std of the burst fixes about it, × the offset
    duplicate_probability: float = 0.0    # fixes delivered twice with the same stamp

    @classmethod
    def real_collar(cls, **overrides) -> 'CollarErrorModel':
        """Every real-collar fault on, as seen on deployed GPS collars: fixes every 30-250 s,
        silences of 6-30 h (about one per 3 days), a third of the collars starting late and
        a third ending early, bursts of 3-10 fixes 0.3-3 km off (one per ~300 fixes),
        0.5 % duplicated stamps."""
        base = dict(fix_interval=140.0, fix_interval_range=(30.0, 250.0),
                    silence_rate=1.0 / (3 * 86400.0), late_start_fraction=1 / 3,
                    early_end_fraction=1 / 3, burst_rate=1.0 / 300.0,
                    duplicate_probability=0.005, outage_rate=0.0, skip_probability=0.0)
        base.update(overrides)
        return cls(**base)

    def __post_init__(self):
        positive = ('fix_interval', 'gm_tau', 'hdop_tau')
        for name in positive:
            if not getattr(self, name) > 0:
                raise HerdInputError(f'collar error model: {name} must be > 0, '
                                     f'got {getattr(self, name)!r}')
        for name in ('multipath_fraction', 'skip_probability', 'no_fix_probability',
                     'nan_alt_probability'):
            if not 0.0 <= getattr(self, name) < 1.0:
                raise HerdInputError(f'collar error model: {name} must be in [0, 1), '
                                     f'got {getattr(self, name)!r}')
        if int(self.multipath_max_fixes) < 1:
            raise HerdInputError('collar error model: multipath_max_fixes must be >= 1')
        for name in ('burst_rate', 'duplicate_probability', 'late_start_fraction',
                     'early_end_fraction'):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise HerdInputError(f'collar error model: {name} must be in [0, 1], '
                                     f'got {getattr(self, name)!r}')
        if self.fix_interval_range is not None:
            lo, hi = self.fix_interval_range
            if not 0 < lo <= hi:
                raise HerdInputError('collar error model: fix_interval_range must be '
                                     f'0 < lo <= hi, got {self.fix_interval_range!r}')

    @property
    def horizontal_std(self) -> float:
        """Nominal per-axis horizontal error std (m) at h = 1."""
        return float(np.hypot(self.horizontal_gm_std, self.horizontal_white_std))

    @property
    def vertical_std(self) -> float:
        """Total vertical error std (m): Gauss-Markov and white parts."""
        return float(np.hypot(self.vertical_gm_std, self.vertical_white_std))


def simulate_collar_fixes(traj: HerdTrajectory, *, seed: int = 0, datum=None,
                          model: CollarErrorModel | None = None) -> pd.DataFrame:
    """The fixes GPS collars on the herd ``traj`` would deliver (see the module docstring).

    Args:
        traj: true positions (T, N, 2), metres ENU about ``datum``, on any sorted clock.
        seed: seed of the random generator; equal seeds give equal tables.
        datum: (lat °, lon °[, alt m]); default ``traj.meta['datum']``, else DEFAULT_DATUM.
        model: the error parameters (default :class:`CollarErrorModel()`).

    Returns:
        The fixes table described in the module docstring, sorted by time.

    Raises:
        HerdInputError: non-finite positions, or a trajectory shorter than one fix interval.
    """
    from herd_ros.ingest.geodesy import enu_to_geodetic

    model = CollarErrorModel() if model is None else model
    datum = tuple(traj.meta.get('datum', DEFAULT_DATUM) if datum is None else datum)
    if len(datum) == 2:
        datum = datum + (0.0,)
    lat0, lon0, alt0 = (float(v) for v in datum[:3])
    times = np.asarray(traj.times, dtype=float)
    pos = np.asarray(traj.positions, dtype=float)
    if pos.ndim != 3 or pos.shape[2] != 2 or pos.shape[0] != len(times) or len(times) < 2:
        raise HerdInputError('collar errors: the trajectory needs times (T,) and positions '
                             '(T, N, 2) with T >= 2')
    if not np.isfinite(pos).all() or not np.isfinite(times).all():
        raise HerdInputError('collar errors: the trajectory has non-finite times or positions')
    if (np.diff(times) <= 0).any():
        raise HerdInputError('collar errors: the trajectory times must increase strictly')
    span = float(times[-1] - times[0])
    n_agents = pos.shape[1]
    rng = np.random.default_rng(seed)
    if model.fix_interval_range is None:
        interval = float(model.fix_interval)
        n_fixes = int(np.floor(span / interval))
    else:
        lo, hi = (float(v) for v in model.fix_interval_range)
        interval = 0.5 * (lo + hi)
        n_fixes = int(np.floor(span / lo)) + 1
    if n_fixes < 1:
        raise HerdInputError(f'collar errors: the trajectory spans {span:g} s, '
                             f'less than one fix interval ({interval:g} s)')
    shape = (n_fixes, n_agents)

    # --- when each collar fixes: own phase, jitter (or duty-cycled intervals), ms stamps ---
    phase = rng.uniform(0.0, interval, n_agents)
    if model.fix_interval_range is None:
        jitter = np.clip(rng.normal(0.0, model.timing_jitter_std, shape), -0.3 * interval,
                         0.3 * interval)
        t_fix = times[0] + phase[None, :] + interval * np.arange(n_fixes)[:, None] + jitter
    else:
        steps = rng.uniform(lo, hi, shape)
        steps[0] = phase
        t_fix = times[0] + np.cumsum(steps, axis=0)
    # duty-cycled collars stop at the end of the data; fixed-rate ones keep the old clipping
    beyond = (t_fix > times[-1]) if model.fix_interval_range is not None else \
        np.zeros(shape, dtype=bool)
    t_fix = np.round(np.clip(t_fix, times[0], times[-1]), 3)
    true_xy = _interpolate(times, pos, t_fix)                            # (K, N, 2)
    # --- correlated + white noise, scaled by an HDOP-like factor ---------------------------
    hdop = np.exp(_gauss_markov(rng, shape, model.hdop_log_std, model.hdop_tau, interval))
    gm_h = _gauss_markov(rng, shape + (2,), model.horizontal_gm_std, model.gm_tau, interval)
    gm_u = _gauss_markov(rng, shape, model.vertical_gm_std, model.gm_tau, interval)
    err_xy = hdop[..., None] * (gm_h + rng.normal(0.0, model.horizontal_white_std, shape + (2,)))
    err_u = hdop * (gm_u + rng.normal(0.0, model.vertical_white_std, shape))

    # --- multipath episodes ----------------------------------------------------------------
    max_len = int(model.multipath_max_fixes)
    p_start = model.multipath_fraction / ((1 + max_len) / 2.0)
    starts = np.argwhere(rng.random(shape) < p_start)                   # (E, 2) [fix, agent]
    lengths = rng.integers(1, max_len + 1, len(starts))
    size = rng.uniform(*model.multipath_offset, len(starts))
    angle = rng.uniform(-np.pi, np.pi, len(starts))
    jump_xy = size[:, None] * np.column_stack([np.cos(angle), np.sin(angle)])
    jump_u = rng.normal(0.0, 0.5, len(starts)) * size
    multipath = np.zeros(shape, dtype=bool)
    offset_xy = np.zeros(shape + (2,))
    offset_u = np.zeros(shape)
    for m in range(max_len):
        rows = starts[:, 0] + m
        sel = (m < lengths) & (rows < n_fixes)
        idx = (rows[sel], starts[sel, 1])
        multipath[idx] = True
        offset_xy[idx] = jump_xy[sel]
        offset_u[idx] = jump_u[sel]

    # --- missing fixes: outages and single skips -------------------------------------------
    outage_starts = np.argwhere(rng.random(shape) < model.outage_rate * interval)
    outage_len = np.ceil(rng.uniform(*model.outage_duration, len(outage_starts))
                         / interval).astype(int)
    edges = np.zeros((n_fixes + int(outage_len.max(initial=0)) + 1, n_agents), dtype=int)
    np.add.at(edges, (outage_starts[:, 0], outage_starts[:, 1]), 1)
    np.add.at(edges, (outage_starts[:, 0] + outage_len, outage_starts[:, 1]), -1)
    in_outage = np.cumsum(edges, axis=0)[:n_fixes] > 0
    delivered = ~in_outage & (rng.random(shape) >= model.skip_probability) & ~beyond

    # --- real-collar faults: silences, late start, early end, outlier bursts ----------------
    # (their own random stream: the fixed-rate model's draws stay what they were)
    frng = np.random.default_rng([seed, 1])
    for i in range(n_agents):
        n_sil = frng.poisson(model.silence_rate * span)
        for start, length in zip(frng.uniform(times[0], times[-1], n_sil),
                                 frng.uniform(*model.silence_duration, n_sil)):
            delivered[:, i] &= ~((t_fix[:, i] >= start) & (t_fix[:, i] < start + length))
    for frac, rng_s, late in ((model.late_start_fraction, model.late_start, True),
                              (model.early_end_fraction, model.early_end, False)):
        k = int(np.ceil(frac * n_agents - 1e-9))            # that share of the collars
        for i in frng.permutation(n_agents)[:k]:
            cut = min(frng.uniform(*rng_s), 0.4 * span)
            delivered[:, i] &= (t_fix[:, i] >= times[0] + cut) if late else \
                (t_fix[:, i] <= times[-1] - cut)
    burst = np.zeros(shape, dtype=bool)
    offset_burst = np.zeros(shape + (2,))
    for k0, i in np.argwhere(frng.random(shape) < model.burst_rate):
        length = int(frng.integers(int(model.burst_fixes[0]), int(model.burst_fixes[1]) + 1))
        size = frng.uniform(*model.burst_offset)
        ang = frng.uniform(-np.pi, np.pi)
        rows = np.arange(k0, min(k0 + length, n_fixes))
        centre = size * np.array([np.cos(ang), np.sin(ang)])
        offset_burst[rows, i] = centre + model.burst_scatter * size / np.sqrt(2.0) \
            * frng.standard_normal((len(rows), 2))
        burst[rows, i] = True

    # --- NO_FIX and NaN altitude ------------------------------------------------------------
    no_fix = rng.random(shape) < model.no_fix_probability
    bad_size = rng.uniform(*model.no_fix_offset, shape)
    bad_angle = rng.uniform(-np.pi, np.pi, shape)
    nan_alt = rng.random(shape) < model.nan_alt_probability

    meas_xy = true_xy + err_xy + offset_xy + offset_burst
    bad_xy = bad_size[..., None] * np.stack([np.cos(bad_angle), np.sin(bad_angle)], axis=-1)
    meas_xy[no_fix] = true_xy[no_fix] + bad_xy[no_fix]
    meas_u = err_u + offset_u
    meas_u[no_fix | nan_alt] = np.nan

    # --- the table --------------------------------------------------------------------------
    keep = delivered
    # a fix without vertical solution still has a horizontal one: convert with its true
    # height error, then blank the altitude
    lat, lon, alt = enu_to_geodetic(meas_xy[..., 0][keep], meas_xy[..., 1][keep],
                                    (err_u + offset_u)[keep], lat0, lon0, alt0)
    var_h = (hdop * model.horizontal_std) ** 2
    var_u = (hdop * model.vertical_std) ** 2
    nf = no_fix[keep]
    agent_idx = np.broadcast_to(np.arange(n_agents), shape)[keep]
    table = pd.DataFrame({
        'time': t_fix[keep],
        'agent': np.asarray(traj.agents, dtype=object)[agent_idx],
        'lat': lat,
        'lon': lon,
        'alt': np.where(np.isnan(meas_u[keep]), np.nan, alt),
        'status': np.where(nf, STATUS_NO_FIX, STATUS_FIX).astype(int),
        'position_covariance_type': np.where(nf, COVARIANCE_TYPE_UNKNOWN,
                                             COVARIANCE_TYPE_APPROXIMATED).astype(int),
        'cov_ee': np.where(nf, np.nan, var_h[keep]),
        'cov_en': np.where(nf, np.nan, 0.0),
        'cov_nn': np.where(nf, np.nan, var_h[keep]),
        'cov_uu': np.where(nf, np.nan, var_u[keep]),
        'true_x': true_xy[..., 0][keep],
        'true_y': true_xy[..., 1][keep],
        'multipath': multipath[keep] & ~nf,
        'burst': burst[keep] & ~nf,
        'duplicate': False,
    })
    dup = table[frng.random(len(table)) < model.duplicate_probability].copy()
    dup['duplicate'] = True
    agent_pos = {a: k for k, a in enumerate(traj.agents)}
    table = pd.concat([table, dup], ignore_index=True)
    order = np.lexsort((table['duplicate'].to_numpy(),
                        table['agent'].map(agent_pos).to_numpy(), table['time'].to_numpy()))
    table = table.iloc[order].reset_index(drop=True)
    table.attrs['datum'] = (lat0, lon0, alt0)
    return table


def _interpolate(times, pos, t):
    """Linear interpolation of positions (T, N, 2) at times t (K, N) of each agent column."""
    k = np.clip(np.searchsorted(times, t, side='right') - 1, 0, len(times) - 2)
    frac = ((t - times[k]) / (times[k + 1] - times[k]))[..., None]
    cols = np.broadcast_to(np.arange(pos.shape[1]), t.shape)
    return (1.0 - frac) * pos[k, cols] + frac * pos[k + 1, cols]


def _gauss_markov(rng, shape, std, tau, dt):
    """Stationary first-order Gauss-Markov sequences along axis 0 (sampled every ``dt``):
    ``x_k = φ x_{k-1} + std √(1-φ²) ξ_k``, ``φ = exp(-dt/tau)``, ``x_0 ~ N(0, std²)``."""
    phi = np.exp(-dt / tau)
    xi = rng.normal(0.0, 1.0, shape)
    x_prev = rng.normal(0.0, std, (1,) + tuple(shape[1:]))
    return lfilter([std * np.sqrt(1.0 - phi ** 2)], [1.0, -phi], xi, axis=0, zi=phi * x_prev)[0]


def write_gps_csv(fixes: pd.DataFrame, path, *, keep_no_fix: bool = False) -> Path:
    """Write fixes as the GPS CSV of doc/formats.md: header ``time,agent,lat,lon,alt``.

    ``time`` with millisecond resolution, lat/lon with 1e-9° (0.1 mm), alt with 1 mm; a NaN
    altitude is an empty field. By default NO_FIX rows (``status == -1``) are dropped, since
    the plain format has no status; with ``keep_no_fix=True`` every row is written and a
    ``status`` column (NavSatStatus codes) is appended, which the project's GPS CSV reader
    understands.

    Raises:
        HerdInputError: a required column is missing.
    """
    missing = [c for c in GPS_CSV_COLUMNS if c not in fixes.columns]
    if missing:
        raise HerdInputError(f'write_gps_csv: the fixes table lacks column(s) '
                             f'{", ".join(missing)}')
    rows = fixes
    if not keep_no_fix and 'status' in fixes.columns:
        rows = fixes[fixes['status'].to_numpy() != STATUS_NO_FIX]
    out = pd.DataFrame({
        'time': _fmt('%.3f', rows['time']),
        'agent': rows['agent'].astype(str).to_numpy(),
        'lat': _fmt('%.9f', rows['lat']),
        'lon': _fmt('%.9f', rows['lon']),
        'alt': _fmt('%.3f', rows['alt']),
    })
    if keep_no_fix:
        status = rows['status'] if 'status' in rows.columns else pd.Series(0, index=rows.index)
        out['status'] = status.astype(int).to_numpy()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    out.to_csv(path, index=False)
    return path


def _fmt(fmt, values):
    values = np.asarray(values, dtype=float)
    text = np.char.mod(fmt, values).astype(object)
    text[~np.isfinite(values)] = ''
    return text


def duty_cycle_recorded_fixes(recorded: pd.DataFrame, *, seed: int = 0,
                              model: CollarErrorModel | None = None) -> pd.DataFrame:
    """A dense real recording seen through duty-cycled collars with real-collar faults.

    Unlike :func:`simulate_collar_fixes`, which adds modelled noise to a true path, this
    keeps the recording's own positions and noise: each collar gets its own schedule (random
    phase, intervals drawn uniformly in ``model.fix_interval_range``), and at each scheduled
    time takes the first recorded fix at or after it (none if the recording has nothing
    before the next scheduled time). Then the faults of ``model`` are applied as in
    :func:`simulate_collar_fixes`: silences, late starts and early ends drop fixes, outlier
    bursts move runs of fixes to a wrong place (flag ``burst``), duplicates repeat a fix
    (flag ``duplicate``). Measurement noise, multipath, NO_FIX and dropouts of the model are
    not added: the recording has its own.

    Args:
        recorded: planar fixes ``time, agent, x, y`` (metres), any order; rows with
            non-finite values are ignored.
        seed: seed of the random generator; equal seeds give equal tables.
        model: the faults (default :meth:`CollarErrorModel.real_collar`).

    Returns:
        ``time, agent, x, y, true_x, true_y, burst, duplicate``, sorted by time then agent;
        ``true_x, true_y`` are the recorded positions (before any burst offset).
    """
    model = CollarErrorModel.real_collar() if model is None else model
    need = [c for c in ('time', 'agent', 'x', 'y') if c not in recorded.columns]
    if need:
        raise HerdInputError(f'duty_cycle_recorded_fixes: the recording lacks column(s) '
                             f'{", ".join(need)}')
    rec = recorded[np.isfinite(recorded[['time', 'x', 'y']].to_numpy(float)).all(axis=1)]
    if model.fix_interval_range is None:
        lo = hi = float(model.fix_interval)
    else:
        lo, hi = (float(v) for v in model.fix_interval_range)
    rng = np.random.default_rng([seed, 2])
    t_all = rec['time'].to_numpy(float)
    start, end = float(t_all.min()), float(t_all.max())
    span = end - start
    agents = sorted(rec['agent'].astype(str).unique())
    late = set(rng.permutation(agents)[:int(np.ceil(model.late_start_fraction * len(agents)
                                                    - 1e-9))])
    early = set(rng.permutation(agents)[:int(np.ceil(model.early_end_fraction * len(agents)
                                                     - 1e-9))])
    parts = []
    for agent in agents:
        g = rec[rec['agent'].astype(str) == agent].sort_values('time', kind='stable')
        t = g['time'].to_numpy(float)
        xy = g[['x', 'y']].to_numpy(float)
        n_sched = int(np.ceil(span / lo)) + 2
        sched = start + rng.uniform(0.0, hi) + np.cumsum(
            np.r_[0.0, rng.uniform(lo, hi, n_sched - 1)])
        sched = sched[sched <= end]
        k = np.searchsorted(t, sched, side='left')
        nxt = np.r_[sched[1:], np.inf]
        ok = k < len(t)
        ok[ok] &= t[k[ok]] < nxt[ok]
        k = np.unique(k[ok])
        tk, pk = t[k], xy[k].copy()
        keep = np.ones(len(k), dtype=bool)
        n_sil = rng.poisson(model.silence_rate * span)
        for s0, length in zip(rng.uniform(start, end, n_sil),
                              rng.uniform(*model.silence_duration, n_sil)):
            keep &= ~((tk >= s0) & (tk < s0 + length))
        if agent in late:
            keep &= tk >= start + min(rng.uniform(*model.late_start), 0.4 * span)
        if agent in early:
            keep &= tk <= end - min(rng.uniform(*model.early_end), 0.4 * span)
        tk, pk = tk[keep], pk[keep]
        true = pk.copy()
        burst = np.zeros(len(tk), dtype=bool)
        for k0 in np.flatnonzero(rng.random(len(tk)) < model.burst_rate):
            length = int(rng.integers(int(model.burst_fixes[0]), int(model.burst_fixes[1]) + 1))
            size = rng.uniform(*model.burst_offset)
            ang = rng.uniform(-np.pi, np.pi)
            rows = np.arange(k0, min(k0 + length, len(tk)))
            centre = size * np.array([np.cos(ang), np.sin(ang)])
            pk[rows] = true[rows] + centre + model.burst_scatter * size / np.sqrt(2.0) \
                * rng.standard_normal((len(rows), 2))
            burst[rows] = True
        parts.append(pd.DataFrame({'time': tk, 'agent': agent, 'x': pk[:, 0], 'y': pk[:, 1],
                                   'true_x': true[:, 0], 'true_y': true[:, 1],
                                   'burst': burst, 'duplicate': False}))
    table = pd.concat(parts, ignore_index=True)
    dup = table[rng.random(len(table)) < model.duplicate_probability].copy()
    dup['duplicate'] = True
    table = pd.concat([table, dup], ignore_index=True)
    order = np.lexsort((table['duplicate'].to_numpy(), table['agent'].to_numpy(),
                        table['time'].to_numpy()))
    return table.iloc[order].reset_index(drop=True)
