"""The offline ingest path: fixes -> datum -> ENU -> collar filters -> herd clock -> smoother.

This is what ``herd-ros ingest`` and ``herd-ros fit`` (given a GPS CSV or a bag) run::

    fixes = load_fixes('cows.mcap')                      # GPS CSV / Movebank / GPX / rosbag2
    traj = trajectory_from_fixes(fixes, dt=1.0, smoother='rts')
    traj.meta['datum'], traj.meta['counters']

Steps (each a module of :mod:`herd_ros.ingest`):

1. **Datum** (:func:`choose_datum`): the given one, or deterministically the first *valid*
   fix in time order (status not NO_FIX, finite lat/lon; ties keep file order); its altitude,
   or 0 if NaN. Unlike navsat_transform's "first message that arrives", it does not depend
   on callback order, and a NO_FIX or NaN fix can never become the datum.
2. **ENU** (:mod:`~herd_ros.ingest.geodesy`): exact WGS84; a NaN altitude is replaced by the
   datum's altitude (a horizontal error of ~1.5 cm per 10 m height error at 10 km).
3. **Filters** (:mod:`~herd_ros.ingest.collar_filter`): one per agent, fixes in stamp order,
   rejections counted per reason.
4. **Clock** (:mod:`~herd_ros.ingest.herd_clock`): ticks k·dt; each agent's causal estimate.
   The trajectory is trimmed to the ticks where every agent is initialised, and the trailing
   ticks where any agent is stale are dropped (a collar that died is not extrapolated to the
   end of the recording). Stale ticks inside remain, flagged in ``meta['stale']``.
5. **Smoother** (:mod:`~herd_ros.ingest.smoothing`): ``'none'`` (causal filter, identical to
   what the ``gps_ingest`` node publishes), ``'rts'`` or ``'fir'``.
"""
from __future__ import annotations

import logging

import numpy as np
import pandas as pd

from herd_ros.errors import HerdInputError
from herd_ros.ingest.collar_filter import COUNTERS, CollarFilter, FilterParams, STATUS_NO_FIX
from herd_ros.ingest.geodesy import geodetic_to_enu
from herd_ros.ingest.herd_clock import (TimelineRecorder, resample_timelines,
                                        tick_grid)
from herd_ros.ingest.smoothing import gaussian_fir, rts_on_ticks
from herd_ros.io.gps_files import normalise_fixes, read_fix_file, sniff_format
from herd_ros.trajectory import HerdTrajectory

log = logging.getLogger(__name__)

SMOOTHERS = ('none', 'rts', 'fir')


def load_fixes(path, fmt: str = 'auto') -> pd.DataFrame:
    """Read fixes from a GPS CSV, Movebank CSV, GPX file, rosbag2 directory or ``.mcap``
    file into a fixes table (see :mod:`herd_ros.io.gps_files`)."""
    fmt = sniff_format(path) if fmt == 'auto' else fmt
    if fmt == 'bag':
        from herd_ros.io.bags import read_fix_bag
        return normalise_fixes(read_fix_bag(path))
    return read_fix_file(path, fmt)


def valid_fix_mask(fixes: pd.DataFrame) -> np.ndarray:
    """Rows that can be positions: status not NO_FIX, finite lat, lon and time."""
    status = fixes['status'].to_numpy() if 'status' in fixes else np.zeros(len(fixes))
    return ((status != STATUS_NO_FIX) & np.isfinite(fixes['lat'].to_numpy(float))
            & np.isfinite(fixes['lon'].to_numpy(float))
            & np.isfinite(fixes['time'].to_numpy(float)))


def choose_datum(fixes: pd.DataFrame, datum=None) -> tuple[float, float, float]:
    """The datum (lat, lon, alt): ``datum`` if given (alt defaults to 0), else the first valid
    fix in time order (alt 0 if NaN)."""
    if datum is not None:
        d = [float(v) for v in datum]
        if len(d) not in (2, 3) or not np.isfinite(d).all():
            raise HerdInputError(f'datum must be LAT,LON[,ALT] finite numbers, got {datum!r}')
        if abs(d[0]) > 90 or abs(d[1]) > 180:
            raise HerdInputError(f'datum {d[:2]} is outside ±90/±180 degrees')
        return d[0], d[1], d[2] if len(d) == 3 else 0.0
    valid = valid_fix_mask(fixes)
    if not valid.any():
        raise HerdInputError('no valid fix (status not NO_FIX, finite lat/lon) to take the '
                             'datum from')
    t = np.where(valid, fixes['time'].to_numpy(float), np.inf)
    k = int(np.argmin(t))           # first minimum: file order breaks ties
    row = fixes.iloc[k]
    alt = float(row['alt']) if 'alt' in fixes and np.isfinite(row['alt']) else 0.0
    return float(row['lat']), float(row['lon']), alt


def auto_stale_after(fixes: pd.DataFrame) -> float:
    """Default ``stale_after``: five median fix intervals, at least 30 s."""
    steps = []
    for _, t in fixes.groupby('agent', sort=False)['time']:
        d = np.diff(np.sort(t.to_numpy(float)))
        steps.append(d[d > 0])
    steps = np.concatenate(steps) if steps else np.array([])
    return float(max(30.0, 5.0 * np.median(steps))) if len(steps) else 30.0


def run_filters(fixes: pd.DataFrame, datum, params: FilterParams, agents=None,
                progress: bool = False):
    """Run one :class:`CollarFilter` per agent over its fixes in stamp order.

    Returns:
        (filters, timelines, reasons): dicts keyed by agent, and a (len(fixes),) array of
        the outcome of every row (``'accepted'``, ``'reinitialised'`` or the rejection
        reason), aligned with ``fixes``.
    """
    lat0, lon0, alt0 = datum
    e, n, _ = geodetic_to_enu(fixes['lat'].to_numpy(float), fixes['lon'].to_numpy(float),
                              fixes['alt'].to_numpy(float), lat0, lon0, alt0, nan_alt=alt0)
    t = fixes['time'].to_numpy(float)
    status = fixes['status'].to_numpy(int)
    cov_type = fixes['position_covariance_type'].to_numpy(int)
    cov = np.zeros((len(fixes), 9))
    cov[:, 0] = fixes['cov_ee'].to_numpy(float)
    cov[:, 1] = cov[:, 3] = fixes['cov_en'].to_numpy(float)
    cov[:, 4] = fixes['cov_nn'].to_numpy(float)
    agents = sorted(set(fixes['agent'])) if agents is None else list(agents)
    reasons = np.empty(len(fixes), dtype=object)
    filters, timelines = {}, {}
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=len(fixes), desc='filtering', unit='fix', leave=False)
    agent_col = fixes['agent'].to_numpy()
    for agent in agents:
        rows = np.flatnonzero(agent_col == agent)
        rows = rows[np.argsort(t[rows], kind='stable')]
        f = CollarFilter(params)
        rec = TimelineRecorder(f)
        for k in rows:
            res = f.update(t[k], e[k], n[k], status=status[k], position_covariance=cov[k],
                           position_covariance_type=cov_type[k])
            reasons[k] = res.reason
            rec.record()
        filters[agent], timelines[agent] = f, rec.timeline()
        if bar is not None:
            bar.update(len(rows))
    if bar is not None:
        bar.close()
    return filters, timelines, reasons


def trajectory_from_fixes(fixes: pd.DataFrame, dt: float, datum=None, smoother: str = 'none',
                          *, agents=None, trim: bool = True, progress: bool = False,
                          fir_taps: int = 30, fir_sigma: float = 6.0,
                          **filter_params) -> HerdTrajectory:
    """Filtered, synchronized herd trajectory from a fixes table.

    Args:
        fixes: the fixes table (columns time, agent, lat, lon, optionally alt, status,
            position_covariance_type, cov_ee, cov_en, cov_nn).
        dt: the herd clock step (s).
        datum: (lat, lon[, alt]) or None for the first valid fix.
        smoother: ``'none'``, ``'rts'`` or ``'fir'``.
        agents: agent order (default: sorted ids, independent of file or bag order).
        trim: cut to the ticks where every agent has an estimate and drop trailing stale
            ticks (see the module docstring); False keeps the whole clock with NaN.
        fir_taps, fir_sigma: the FIR's n and σ (steps).
        **filter_params: :class:`FilterParams` fields (accel_std, default_position_std,
            gate_probability, max_speed, stale_after, ...). ``stale_after`` defaults to
            :func:`auto_stale_after`.

    Returns:
        A :class:`HerdTrajectory` with ``meta``: ``datum`` (lat, lon, alt), ``counters``
        {agent: {reason: count}}, ``stale`` (T, N), ``velocities``, ``position_cov``,
        ``smoother``, ``filter_params``, ``trimmed`` (leading, trailing ticks dropped).
    """
    if not (np.isfinite(dt) and dt > 0):
        raise HerdInputError(f'dt must be a positive number of seconds, got {dt!r}')
    if smoother not in SMOOTHERS:
        raise HerdInputError(f'smoother must be one of {", ".join(SMOOTHERS)}, got '
                             f'{smoother!r}')
    missing = [c for c in ('time', 'agent', 'lat', 'lon') if c not in fixes.columns]
    if missing:
        raise HerdInputError(f'fixes table lacks column(s) {", ".join(missing)}')
    fixes = normalise_fixes(fixes)
    if agents is not None:
        unknown = sorted(set(agents) - set(fixes['agent']))
        if unknown:
            raise HerdInputError(f'agent(s) {", ".join(unknown)} have no fixes')
        fixes = fixes[fixes['agent'].isin(agents)].reset_index(drop=True)
    if 'stale_after' not in filter_params or filter_params['stale_after'] is None:
        filter_params['stale_after'] = auto_stale_after(fixes)
    params = FilterParams(**filter_params)
    datum = choose_datum(fixes, datum)
    log.info('datum lat %.9f lon %.9f alt %.3f', *datum)
    filters, timelines, reasons = run_filters(fixes, datum, params, agents, progress)
    agents = list(filters)
    counters = {a: dict(filters[a].counters) for a in agents}
    empty = [a for a in agents if len(timelines[a].t) == 0]
    if empty:
        raise HerdInputError(f'agent(s) {", ".join(empty)} have no usable fix (all rejected: '
                             + '; '.join(f'{a}: {_summary(counters[a])}' for a in empty) + ')')
    stamps = fixes['time'].to_numpy(float)
    stamps = stamps[np.isfinite(stamps)]
    ticks = tick_grid(stamps.min(), stamps.max(), dt)
    traj = resample_timelines(timelines, ticks, agents)
    lead = trail = 0
    if trim:
        init_all = traj.meta['initialised'].all(axis=1)
        stale_any = traj.meta['stale'].any(axis=1)
        if not init_all.any():
            raise HerdInputError('the agents have no time in common: no tick where every '
                                 'agent has an accepted fix before it')
        lead = int(np.argmax(init_all))
        ok_end = ~stale_any & init_all
        last = len(ticks) - 1 - int(np.argmax(ok_end[::-1])) if ok_end.any() else lead
        trail = len(ticks) - 1 - last
        traj = _slice(traj, lead, last + 1)
    if smoother == 'rts':
        for i, a in enumerate(agents):
            x, P = rts_on_ticks(timelines[a], traj.times)
            traj.positions[:, i] = x[:, :2]
            traj.meta['velocities'][:, i] = x[:, 2:]
            traj.meta['position_cov'][:, i] = P[:, :2, :2]
            traj.meta['state_cov'][:, i] = P
    elif smoother == 'fir':
        if not np.isfinite(traj.positions).all():
            raise HerdInputError('the FIR smoother needs every agent at every tick; use '
                                 'trim=True')
        traj.positions = gaussian_fir(traj.positions, fir_taps, fir_sigma)
    traj.meta.update({'datum': datum, 'counters': counters, 'smoother': smoother,
                      'filter_params': params, 'trimmed': (lead, trail),
                      'fix_outcomes': reasons})
    return traj


def _slice(traj: HerdTrajectory, start: int, stop: int) -> HerdTrajectory:
    meta = {k: (v[start:stop].copy() if isinstance(v, np.ndarray) else v)
            for k, v in traj.meta.items()}
    return HerdTrajectory(traj.times[start:stop].copy(), list(traj.agents),
                          traj.positions[start:stop].copy(), traj.run, meta)


def _summary(counter: dict) -> str:
    return ', '.join(f'{k} {v}' for k, v in counter.items() if v)


def format_counters(counters: dict) -> str:
    """A small table of per-agent counters (rows: agents, columns: :data:`COUNTERS`)."""
    names = list(COUNTERS)
    short = [c.replace('rejected_', '') for c in names]
    width = max([len('agent')] + [len(a) for a in counters])
    lines = ['  '.join([f'{"agent":<{width}}'] + [f'{s:>8}' for s in short])]
    for agent, c in counters.items():
        lines.append('  '.join([f'{agent:<{width}}'] + [f'{c.get(k, 0):>8}' for k in names]))
    return '\n'.join(lines)
