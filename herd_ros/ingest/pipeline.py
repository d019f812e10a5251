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
4. **Clock** (:mod:`~herd_ros.ingest.herd_clock`): ticks k·dt; each agent's causal estimate,
   NaN where the collar is stale (no accepted fix within ``stale_after``: never an
   extrapolation across a silence). The clock covers the union of the collars' spans: it is
   trimmed only to the ticks from the first to the last where *any* agent has a position, so
   no collar loses a fix; late starts, early ends and silences stay NaN (flagged in
   ``meta['stale']``), and the fit skips them.
5. **Smoother** (:mod:`~herd_ros.ingest.smoothing`): ``'none'`` (causal filter, identical to
   what the ``gps_ingest`` node publishes), ``'rts'`` or ``'fir'``.
"""
from __future__ import annotations

import logging
import math
import time as _time
from dataclasses import dataclass

import numpy as np
import pandas as pd

from herd_ros.errors import HerdInputError
from herd_ros.ingest.collar_filter import COUNTERS, CollarFilter, FilterParams, STATUS_NO_FIX
from herd_ros.ingest.geodesy import geodetic_to_enu
from herd_ros.ingest import collar_bank
from herd_ros.ingest.herd_clock import (StateTimeline, TimelineRecorder, resample_timelines,
                                        tick_grid, walk_of)
from herd_ros.ingest.stamp_guards import MAX_STAMP_AHEAD_S, future_stamps
from herd_ros.ingest.tracking_score import taken
from herd_ros.io.gps_files import normalise_fixes, read_fix_file, sniff_format
from herd_ros.trajectory import HerdTrajectory

log = logging.getLogger(__name__)

SMOOTHERS = ('none', 'rts', 'lag', 'fir')
#: the motion-model choices of :func:`trajectory_from_fixes`
MOTIONS = ('auto', 'fit', 'fixed')


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


def fix_intervals(fixes: pd.DataFrame, max_gap: float = 3600.0) -> np.ndarray:
    """Every collar's positive intervals between consecutive fixes (s), silences longer
    than ``max_gap`` left out (they say when a collar was off, not how often it fixes)."""
    steps = []
    for _, t in fixes.groupby('agent', sort=False)['time']:
        d = np.diff(np.sort(t.to_numpy(float)))
        steps.append(d[(d > 0) & (d <= max_gap)])
    return np.concatenate(steps) if steps else np.array([])


def auto_stale_after(fixes: pd.DataFrame) -> float:
    """Default ``stale_after``: three times the 90th percentile of the fix intervals (a
    collar that missed two fixes in a row is still carried), at least 30 s."""
    steps = fix_intervals(fixes)
    return float(max(30.0, 3.0 * np.percentile(steps, 90))) if len(steps) else 30.0


#: Herd clock steps :func:`auto_dt` chooses from (s).
NICE_STEPS = (1.0, 2.0, 5.0, 10.0, 15.0, 20.0, 30.0, 60.0, 120.0, 300.0, 600.0, 900.0,
              1800.0, 3600.0)


def _clock_intervals(fixes: pd.DataFrame) -> np.ndarray:
    """:func:`fix_intervals`, or one clear error when there are none to choose a clock by."""
    steps = fix_intervals(fixes)
    if not len(steps):
        raise HerdInputError('cannot choose the herd clock step: no collar has two fixes '
                             'at different times; give --dt')
    return steps


def auto_dt(fixes: pd.DataFrame) -> float:
    """Default herd clock step: the median fix interval, rounded to the nearest round step
    (:data:`NICE_STEPS`, nearest on a log scale): one tick per fix of a typical collar."""
    med = float(np.median(_clock_intervals(fixes)))
    nice = np.asarray(NICE_STEPS)
    return float(nice[np.argmin(np.abs(np.log(nice / med)))])


def track_dt(fixes: pd.DataFrame) -> float:
    """Default clock step of a track that is itself the product (``herd-ros ingest``): the
    largest round step (:data:`NICE_STEPS`) not above the 10th percentile of the fix
    intervals (nor below a tenth of their median), so the clock ticks between nearly any two
    consecutive fixes of a collar and every fix is in the track within a step of its
    arrival. On the herd clock of
    :func:`auto_dt` (one tick per typical fix interval) a fix that arrives after a tick
    waits a whole interval: on collars fixing every 30-300 s the track's last pose before
    a fix was then older than the last raw fix, and lost to it (tracking benchmark). The
    live ``gps_ingest`` ticks at 1 s by default for the same reason; a model is fitted on
    :func:`auto_dt`'s clock, one step per fix."""
    steps = _clock_intervals(fixes)
    # at most ten ticks per median interval: collars that mix bursts of 1 s fixes into a
    # 5 min duty cycle would otherwise write a tick per second for months
    low = max(float(np.percentile(steps, 10)), float(np.median(steps)) / 10.0)
    nice = np.asarray(NICE_STEPS)
    fit = nice[nice <= low * (1 + 1e-9)]
    return float(fit[-1]) if len(fit) else float(nice[0])


#: Motion model of the offline path and the node unless told otherwise: a correlated random
#: walk whose velocity forgets itself in two minutes (stationary speed std 0.39 m/s per
#: axis), right for walking and grazing animals fixed every second to every few minutes.
DEFAULT_ACCEL_STD = 0.05
DEFAULT_VELOCITY_TAU = 120.0
#: The walk component of a collar whose motion is fitted, and its prior before the first
#: fit (:func:`with_walk`): a walking animal. Cattle walk to water at about 1 m/s (baboons
#: travel at 0.5-1 m/s); with :data:`DEFAULT_VELOCITY_TAU` the stationary speed std is
#: σ_a √(τ_v / 2) = 0.77 m/s per axis, 1.1 m/s in the plane. The grazing and resting
#: animal is the collar's own fitted model.
DEFAULT_WALK_ACCEL_STD = 0.1


def auto_filter_params(fixes: pd.DataFrame, **given) -> dict:
    """Defaults for the filter parameters not in ``given`` (None = default): the motion
    model (:data:`DEFAULT_ACCEL_STD`, :data:`DEFAULT_VELOCITY_TAU`) and, from the data,
    ``stale_after`` (:func:`auto_stale_after`) and ``reinit_after_gap`` (at least
    ``stale_after``, at least 300 s)."""
    out = {k: v for k, v in given.items() if v is not None}
    out.setdefault('accel_std', DEFAULT_ACCEL_STD)
    out.setdefault('velocity_tau', DEFAULT_VELOCITY_TAU)
    out.setdefault('stale_after', auto_stale_after(fixes))
    out.setdefault('reinit_after_gap', max(300.0, float(out['stale_after'])))
    return out


def planar_fixes(table: pd.DataFrame) -> pd.DataFrame:
    """A fixes table from planar positions (``time, agent, x, y`` in metres, e.g. a
    real-time location system or an irregular trajectory CSV): columns ``east``/``north``
    carry the positions and no geodetic conversion is made."""
    out = pd.DataFrame({'time': table['time'].to_numpy(float),
                        'agent': table['agent'].astype(str).to_numpy(),
                        'lat': np.nan, 'lon': np.nan,
                        'east': table['x'].to_numpy(float),
                        'north': table['y'].to_numpy(float)})
    return normalise_fixes(out)


def is_planar(fixes: pd.DataFrame) -> bool:
    """The table holds planar positions (:func:`planar_fixes`), not lat/lon."""
    return 'east' in fixes.columns and 'north' in fixes.columns


def fixes_enu(fixes: pd.DataFrame, datum) -> tuple[np.ndarray, np.ndarray]:
    """(east, north) (m) of every row about ``datum`` (None for a planar table)."""
    if is_planar(fixes):
        return fixes['east'].to_numpy(float), fixes['north'].to_numpy(float)
    lat0, lon0, alt0 = datum
    e, n, _ = geodetic_to_enu(fixes['lat'].to_numpy(float), fixes['lon'].to_numpy(float),
                              fixes['alt'].to_numpy(float), lat0, lon0, alt0, nan_alt=alt0)
    return e, n


#: the smallest measurement std (m) the motion fit may find for planar fixes without a
#: covariance (RTLS/UWB tags are centimetre-precise). GPS fixes keep the filter's
#: ``position_std_floor``: at 1 Hz a receiver's error wanders slowly, and a fit left free
#: takes it for motion and trusts every fix to a few centimetres.
PLANAR_STD_FLOOR = 0.02


def refit_config(params: FilterParams, window: int = 200, planar: bool = False,
                 lag_s: float | None = None, collars: int = 1):
    """The :class:`~herd_ros.ingest.motion_refit.RefitConfig` of a filter whose motion
    model is fitted per collar: ``params``' walk component (its configured model if it has
    none); the fitted fix std floored at ``position_std_floor`` (GPS) or
    :data:`PLANAR_STD_FLOOR` (planar fixes); a new model filters from ``lag_s`` after its
    refit point (None or negative: :func:`~herd_ros.ingest.motion_refit.refit_lag` of a
    herd of ``collars``)."""
    from herd_ros.ingest.motion_refit import RefitConfig, refit_lag
    lag_s = refit_lag(collars, lag_s)
    walk = params.walk or (params.accel_std, params.velocity_tau)
    floor = min(PLANAR_STD_FLOOR, params.position_std_floor) if planar \
        else params.position_std_floor
    walk_std = (params.walk_position_std if params.walk_position_std is not None
                else params.default_position_std)
    return RefitConfig(window=window, walk=(walk[0], walk[1], params.walk_probability,
                                            walk_std ** 2), std_floor=floor,
                       lag_s=float(lag_s))


#: velocity persistence (s) of the prior random walk of a collar not yet fitted
PRIOR_VELOCITY_TAU = 0.1


def with_walk(params: FilterParams, walk_accel_std: float | None = None) -> FilterParams:
    """The filter of a collar whose motion is fitted, before its first fit: the walk
    component is the correlated random walk of ``walk_accel_std`` (None: ``params``'
    ``accel_std``) and ``params``' velocity_tau, and its own model is the random walk with
    the walk's long-run diffusion (D = σ_a² τ_v², the fixes followed closely, without
    carrying a velocity across the intervals) until the data say otherwise; the walk
    component's fixes count with the configured ``default_position_std`` added (a glitch
    of a few metres is discounted, not rejected). ``params`` that already have a walk
    component are returned as they are."""
    if params.walk is not None:
        return params
    import dataclasses
    accel = params.accel_std if walk_accel_std is None else float(walk_accel_std)
    if not (np.isfinite(accel) and accel > 0):
        raise HerdInputError(f'filter parameter walk_accel_std must be positive, got '
                             f'{walk_accel_std!r}')
    tau = params.velocity_tau if params.velocity_tau > 0 else 120.0
    D = (accel * tau) ** 2
    return dataclasses.replace(params, accel_std=math.sqrt(D) / PRIOR_VELOCITY_TAU,
                               velocity_tau=PRIOR_VELOCITY_TAU,
                               walk_accel_std=accel,
                               walk_velocity_tau=params.velocity_tau,
                               walk_position_std=params.default_position_std)


def with_motion(params: FilterParams, fit) -> FilterParams:
    """``params`` with the motion model of ``fit`` (a
    :class:`~herd_ros.ingest.motion_fit.MotionFit`, or None: ``params`` unchanged); the
    model of ``params`` becomes the walk model (:attr:`FilterParams.walk`)."""
    if fit is None:
        return params
    import dataclasses
    accel_std, velocity_tau, std, floor = fitted_motion(params, fit)
    walk = params.walk or (params.accel_std, params.velocity_tau)
    return dataclasses.replace(params, accel_std=accel_std, velocity_tau=velocity_tau,
                               walk_accel_std=walk[0], walk_velocity_tau=walk[1],
                               default_position_std=std, position_std_floor=floor)


def fitted_motion(params: FilterParams, fit) -> tuple[float, float, float, float]:
    """What a collar filtered with ``params`` takes from ``fit`` (a
    :class:`~herd_ros.ingest.motion_fit.MotionFit`): (σ_a, τ_v, the std of its fixes without
    a covariance, the smallest std of any fix) — the fields :func:`with_motion` sets, without
    building the parameters (a refit sets them on a bank's collars)."""
    if not np.isfinite(fit.position_std):
        return (fit.accel_std, fit.velocity_tau, params.default_position_std,
                params.position_std_floor)
    # a fitted std is the data's word: the floor (a guard against receivers that claim
    # too much) does not raise it (nor, times a fix's HDOP, its least HDOP's share)
    floor = min(fit.position_std, params.position_std_floor)
    if getattr(fit, 'hdop', False):
        floor = min(floor, fit.position_std * MIN_HDOP)
    return (fit.accel_std, fit.velocity_tau, fit.position_std, floor)


#: the HDOP below which a fix's std σ_m·HDOP is floored (a receiver's best)
MIN_HDOP = 0.5


#: the filter implementations of :func:`run_filters`
ENGINES = ('bank', 'filterpy')


@dataclass
class CollarSummary:
    """What the offline path keeps of one collar's filter: its parameters (its last
    motion model), its counters (keys :data:`~herd_ros.ingest.collar_filter.COUNTERS`),
    its final time ``t`` and its last fitted motion model ``fit`` (None if never fitted)."""

    params: FilterParams
    counters: dict
    t: float
    fit: object = None


def run_filters(fixes: pd.DataFrame, datum, params: FilterParams, agents=None,
                progress: bool = False, engine: str = 'bank', refit=None, enu=None):
    """Run every agent's collar filter over its fixes in stamp order (``datum`` None for a
    planar table).

    ``engine`` ``'bank'``: all collars in one :class:`~herd_ros.ingest.collar_bank.CollarBank`
    (compiled; the default and the node's). ``'filterpy'``: one
    :class:`~herd_ros.ingest.collar_filter.CollarFilter` per agent (the reference). Both
    give the same outcomes and states (to rounding, ~1e-13 m; ``test_collar_bank.py``).
    ``refit`` (a :class:`~herd_ros.ingest.motion_refit.RefitConfig`, or None): each
    collar's motion model is refitted as its fixes arrive, on the causal schedule of
    :mod:`~herd_ros.ingest.motion_refit` (the node's), ``params``' model its prior and
    walk component. ``enu``: the rows' (east, north) if already computed
    (:func:`fixes_enu`).

    Returns:
        (collars, timelines, reasons): dicts keyed by agent (:class:`CollarSummary`,
        :class:`~herd_ros.ingest.herd_clock.StateTimeline`), and a (len(fixes),) array of
        the outcome of every row (``'accepted'``, ``'reinitialised'`` or the rejection
        reason; None for rows of agents not asked for), aligned with ``fixes``.
    """
    if engine not in ENGINES:
        raise HerdInputError(f'engine must be one of {", ".join(ENGINES)}, got {engine!r}')
    e, n = fixes_enu(fixes, datum) if enu is None else enu
    t = fixes['time'].to_numpy(float)
    status = fixes['status'].to_numpy(int)
    cov_type = fixes['position_covariance_type'].to_numpy(int)
    cov = np.zeros((len(fixes), 9))
    cov[:, 0] = fixes['cov_ee'].to_numpy(float)
    cov[:, 1] = cov[:, 3] = fixes['cov_en'].to_numpy(float)
    cov[:, 4] = fixes['cov_nn'].to_numpy(float)
    agent_col = fixes['agent'].to_numpy(dtype=object)
    agents = sorted(pd.unique(agent_col)) if agents is None else list(agents)
    hdop = fixes['hdop'].to_numpy(float) if 'hdop' in fixes.columns else None
    if refit is not None:
        params = with_walk(params)
    if engine == 'bank' and collar_bank.AVAILABLE:
        return _run_bank(agents, agent_col, t, e, n, status, cov_type, cov, params, progress,
                         refit, hdop=hdop)
    from herd_ros.ingest.motion_refit import MotionRefitter, fix_hdop, fix_variance
    var = fix_variance(cov_type, cov[:, 0], cov[:, 4], params.position_std_floor, hdop)
    h = fix_hdop(var)
    reasons = np.empty(len(fixes), dtype=object)
    collars, timelines = {}, {}
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=len(fixes), desc='filtering', unit='fix', leave=False)
    for agent in agents:
        rows = np.flatnonzero(agent_col == agent)
        rows = rows[np.argsort(t[rows], kind='stable')]
        f = CollarFilter(params)
        rec = TimelineRecorder(f)
        refitter = MotionRefitter(1, refit) if refit is not None else None

        in_force = [None]           # the fitted model the filter runs with

        def use(fit, f=f, in_force=in_force):
            f.params = with_motion(params, fit)
            in_force[0] = fit

        for k in rows:
            if refitter is not None:
                # the models scheduled by this fix's stamp take over (motion_refit: lag_s)
                refitter.take_over(0, t[k], use)
            c, ct = cov[k], cov_type[k]
            if np.isfinite(h[k]) and in_force[0] is not None and in_force[0].hdop:
                # the fix's std is the fitted σ_m times its HDOP (motion_fit.fit_motion)
                c = np.zeros(9)
                c[0] = c[4] = (f.params.default_position_std * h[k]) ** 2
                ct = 1
            res = f.update(t[k], e[k], n[k], status=status[k], position_covariance=c,
                           position_covariance_type=ct)
            reasons[k] = res.reason
            rec.record()
            if refitter is not None:
                refitter.observe([0], t[k:k + 1], e[k:k + 1], n[k:k + 1], var[k:k + 1],
                                 [res.accepted])
                if refitter.due([0], refitter.seen - 1)[0]:
                    fits = refitter.refit([0])
                    if fits:
                        refitter.schedule(0, t[k], fits[0])
        collars[agent] = CollarSummary(f.params, dict(f.counters), f.t,
                                       refitter.fits[0] if refitter is not None else None)
        timelines[agent] = rec.timeline()
        if bar is not None:
            bar.update(len(rows))
    if bar is not None:
        bar.close()
    return collars, timelines, reasons


def _run_bank(agents, agent_col, t, e, n, status, cov_type, cov, params, progress, refit,
              chunk: int = 1_000_000, hdop=None):
    """:func:`run_filters` on a :class:`~herd_ros.ingest.collar_bank.CollarBank`: every
    fix of the asked agents, each collar's in stamp order (stable, as the reference). With
    refits, in rounds: every collar's fixes up to its next refit point, then the next
    round (:func:`~herd_ros.ingest.motion_refit.process_with_refits` refits between)."""
    from herd_ros.ingest.motion_refit import (MotionRefitter, fix_variance,
                                              process_with_refits, refit_rounds)
    ids, uniques = pd.factorize(agent_col)
    codes = pd.Index(agents).get_indexer(uniques)[ids]
    rows = np.flatnonzero(codes >= 0)
    rows = rows[np.lexsort((t[rows], codes[rows]))]
    who = codes[rows]
    bounds = np.searchsorted(who, np.arange(len(agents) + 1))   # rows sorted by agent
    bank = collar_bank.CollarBank(len(agents), params)
    m = len(rows)

    def covariance_rows(r):
        # no fix with a covariance type: its rows are never read, so not copied
        return cov[r] if cov_type[r].any() else np.broadcast_to(np.nan, (len(r), 9))

    refitter = None
    if refit is not None:
        refitter = MotionRefitter(len(agents), refit)
        # rounds: a fix's round is how many events of its collar came before it, its refit
        # points and the fixes at which their models take over
        order = np.lexsort((np.arange(m), refit_rounds(t[rows], bounds, refit)))
        var = fix_variance(cov_type, cov[:, 0], cov[:, 4], params.position_std_floor, hdop)
        r = rows[order]
        out, motion = process_with_refits(bank, refitter, codes[r], t[r], e[r], n[r],
                                          status[r], cov_type[r], covariance_rows(r),
                                          var[r])
        # the results stay in round order: each collar's rows are read through `at`
        at = np.empty(m, np.int64)
        at[order] = np.arange(m)
    else:
        at = None
        out = collar_bank.FixBatch.empty(m)
        motion = np.empty((m, 2))
        motion[:, 0] = params.accel_std
        motion[:, 1] = params.velocity_tau
        R = bank.measurement_covariances(cov_type[rows], covariance_rows(rows), codes[rows])
        bar = None
        if progress and m > chunk:
            from tqdm import tqdm
            bar = tqdm(total=m, desc='filtering', unit='fix', leave=False)
        step = chunk if bar is not None else max(m, 1)
        for s in range(0, m, step):
            sl = slice(s, s + step)
            r = rows[sl]
            bank.process(codes[r], t[r], e[r], n[r], status[r], R[sl],
                         out=out.rows(sl))
            if bar is not None:
                bar.update(len(r))
        if bar is not None:
            bar.close()
    outcome = out.outcome if at is None else out.outcome[at]      # by collar, then time
    names = np.array(collar_bank.OUTCOMES, dtype=object)
    reasons = np.full(len(t), None, dtype=object)
    reasons[rows] = names[outcome]
    accepted = outcome <= collar_bank.REINITIALISED
    collars, timelines = {}, {}
    for i, agent in enumerate(agents):
        sl = slice(bounds[i], bounds[i + 1])
        keep = np.flatnonzero(accepted[sl]) + bounds[i]     # the collar's accepted rows
        take = keep if at is None else at[keep]             # ... in `out`
        fit = refitter.fits[i] if refitter is not None else None
        p = with_motion(params, fit)
        timelines[agent] = StateTimeline(t[rows[keep]], out.x[take], out.P[take],
                                         p.accel_std, p.stale_after, out.segment[take],
                                         p.velocity_tau,
                                         motion[take] if refit is not None else None,
                                         walk_of(params))
        collars[agent] = CollarSummary(p, bank.counter_dict(i), float(bank.t[i]), fit)
    return collars, timelines, reasons


def trajectory_from_fixes(fixes: pd.DataFrame, dt: float | None = None, datum=None,
                          smoother: str = 'none',
                          *, agents=None, trim: bool = True, progress: bool = False,
                          fir_taps: int = 30, fir_sigma: float = 6.0, lag: int = 3,
                          engine: str = 'bank', motion_model: str = 'auto',
                          now: float | None = None,
                          max_stamp_ahead_s: float = MAX_STAMP_AHEAD_S,
                          refit_lag_s: float | None = None,
                          **filter_params) -> HerdTrajectory:
    """Filtered, synchronized herd trajectory from a fixes table.

    Args:
        fixes: the fixes table (columns time, agent, lat, lon, optionally alt, status,
            position_covariance_type, cov_ee, cov_en, cov_nn).
        dt: the herd clock step (s); None = :func:`auto_dt`.
        datum: (lat, lon[, alt]) or None for the first valid fix (ignored for a planar
            table, :func:`planar_fixes`).
        smoother: ``'none'``, ``'rts'``, ``'lag'`` (fixed-lag: each tick given the next
            ``lag`` fixes of its collar, :func:`~herd_ros.ingest.smoothing
            .fixed_lag_timeline`) or ``'fir'``.
        agents: agent order (default: sorted ids, independent of file or bag order).
        trim: cut the leading and trailing ticks where no agent has an estimate (the clock
            covers the union of the collars' spans; see the module docstring); False keeps
            the whole clock with NaN.
        fir_taps, fir_sigma: the FIR's n and σ (steps).
        engine: ``'bank'`` (compiled, default) or ``'filterpy'`` (the reference); see
            :func:`run_filters`.
        motion_model: ``'fit'``: each collar's motion model (and the std of its fixes
            without a covariance) refitted by maximum likelihood as its fixes arrive
            (:mod:`~herd_ros.ingest.motion_refit`, :mod:`~herd_ros.ingest.motion_fit`;
            the walk of ``walk_accel_std`` (None or absent:
            :data:`DEFAULT_WALK_ACCEL_STD`) and ``velocity_tau`` is the prior and the walk
            component, :func:`with_walk`); ``'fixed'``: one model for all,
            ``accel_std``/``velocity_tau``; ``'auto'`` (default): ``'fit'`` unless
            ``accel_std`` or ``velocity_tau`` is given.
        refit_lag_s: with ``motion_model`` ``'fit'``, the data time (s) from a collar's
            refit point to the first fix its new model filters (None: the herd's, as the
            ``gps_ingest`` node's default, :func:`~herd_ros.ingest.motion_refit.refit_lag`).
        now, max_stamp_ahead_s: a fix stamped more than ``max_stamp_ahead_s`` after ``now``
            (default: the wall clock) is rejected (outcome ``future``, counter
            ``rejected_future``), as ``gps_ingest`` does (:mod:`~herd_ros.ingest
            .stamp_guards`).
        **filter_params: :class:`FilterParams` fields (accel_std, default_position_std,
            gate_probability, max_speed, stale_after, ...); None or absent
            ``stale_after`` and ``reinit_after_gap`` come from the data
            (:func:`auto_filter_params`).

    Returns:
        A :class:`HerdTrajectory` with ``meta``: ``datum`` (lat, lon, alt), ``counters``
        {agent: {reason: count}}, ``stale`` (T, N), ``velocities``, ``position_cov``,
        ``smoother``, ``filter_params``, ``trimmed`` (leading, trailing ticks dropped),
        ``fix_outcomes`` (per row of ``fixes``), ``motion_fits`` ({agent:
        :class:`~herd_ros.ingest.motion_fit.MotionFit`} or None) and ``timelines`` ({agent:
        :class:`~herd_ros.ingest.herd_clock.StateTimeline`}: each collar's causal track,
        its state after every accepted fix) and ``raw_fixes`` (:func:`raw_fixes_by_agent`).
    """
    if dt is not None and not (np.isfinite(dt) and dt > 0):
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
    future = future_stamps(fixes['time'].to_numpy(float),
                           _time.time() if now is None else float(now), max_stamp_ahead_s)
    all_fixes = fixes
    if future.any():
        fixes = fixes[~future].reset_index(drop=True)
        if fixes.empty:
            raise HerdInputError(f'every fix is stamped more than {max_stamp_ahead_s:g} s after '
                                 f'the wall clock (the first at {all_fixes["time"].min():.3f})')
    if dt is None:
        dt = auto_dt(fixes)
    walk_accel_std = filter_params.pop('walk_accel_std', None)
    params = FilterParams(**auto_filter_params(fixes, **filter_params))
    if is_planar(fixes):
        datum = None
    else:
        datum = choose_datum(fixes, datum)
        log.info('datum lat %.9f lon %.9f alt %.3f', *datum)
    if motion_model not in MOTIONS:
        raise HerdInputError(f'motion_model must be one of {", ".join(MOTIONS)}, got '
                             f'{motion_model!r}')
    if motion_model == 'auto':
        given = {k for k in ('accel_std', 'velocity_tau') if filter_params.get(k) is not None}
        motion_model = 'fixed' if given else 'fit'
    refit = None
    if motion_model == 'fit':
        params = with_walk(params, DEFAULT_WALK_ACCEL_STD if walk_accel_std is None
                           else walk_accel_std)
        refit = refit_config(params, planar=is_planar(fixes), lag_s=refit_lag_s,
                             collars=fixes['agent'].nunique())
    enu = fixes_enu(fixes, datum)
    collars, timelines, reasons = run_filters(fixes, datum, params, agents, progress, engine,
                                              refit, enu)
    fits = {a: c.fit for a, c in collars.items()} if refit is not None else None
    agents = list(collars)
    counters = {a: dict(collars[a].counters) for a in agents}
    empty = [a for a in agents if len(timelines[a].t) == 0]
    if empty:
        raise HerdInputError(f'agent(s) {", ".join(empty)} have no usable fix (all rejected: '
                             + '; '.join(f'{a}: {_summary(counters[a])}' for a in empty) + ')')
    ticks = clock_ticks(fixes, timelines, dt, trim)
    traj = resample_timelines(timelines, ticks, agents)
    lead = trail = 0
    if trim:
        ok = np.isfinite(traj.positions[..., 0]).any(axis=1)
        if not ok.any():
            raise HerdInputError('no agent has a fresh position at any tick')
        lead = int(np.argmax(ok))
        last = len(ticks) - 1 - int(np.argmax(ok[::-1]))
        trail = len(ticks) - 1 - last
        traj = _slice(traj, lead, last + 1)
    if smoother in ('rts', 'lag'):
        from herd_ros.ingest.smoothing import rts_on_ticks
        for i, a in enumerate(agents):
            x, P = rts_on_ticks(timelines[a], traj.times,
                                lag=int(lag) if smoother == 'lag' else None)
            traj.positions[:, i] = x[:, :2]
            traj.meta['velocities'][:, i] = x[:, 2:]
            traj.meta['position_cov'][:, i] = P[:, :2, :2]
    elif smoother == 'fir':
        from herd_ros.ingest.smoothing import gaussian_fir
        if not np.isfinite(traj.positions).all():
            raise HerdInputError('the FIR smoother needs every agent at every tick; use '
                                 'trim=True')
        traj.positions = gaussian_fir(traj.positions, fir_taps, fir_sigma)
    traj.meta['raw_fixes'] = raw_fixes_by_agent(fixes, datum, agents, enu)
    if future.any():
        full = np.full(len(all_fixes), 'future', dtype=object)
        full[~future] = reasons
        reasons = full
        late = all_fixes.loc[future, 'agent'].value_counts()
        for a in counters:
            counters[a]['rejected_future'] = int(late.get(a, 0))
    traj.meta.update({'datum': datum, 'dt': float(dt), 'counters': counters,
                      'smoother': smoother,
                      'filter_params': params, 'trimmed': (lead, trail),
                      'motion_fits': fits, 'motion_model': motion_model,
                      'timelines': timelines,
                      'fix_outcomes': reasons})
    return traj


#: most ticks × collars one herd clock may hold (8 bytes × 2 coordinates each: 3.2 GB)
MAX_CLOCK_CELLS = 2e8


def clock_ticks(fixes: pd.DataFrame, timelines: dict, dt: float, trim: bool) -> np.ndarray:
    """The herd clock's ticks: over the union of the collars' spans — of their accepted
    fixes when ``trim`` (a rejected fix stamped decades off, a collar's boot stamp 0, never
    stretches the clock), else of every stamp. A clock too long to hold (more than
    :data:`MAX_CLOCK_CELLS` ticks × collars: data time that jumps by years) is a
    :class:`HerdInputError` naming the largest jump, where the live node restarts its clock.
    """
    if trim:
        stamps = np.concatenate([np.asarray(tl.t, float) for tl in timelines.values()])
    else:
        stamps = fixes['time'].to_numpy(float)
    stamps = np.sort(stamps[np.isfinite(stamps)])
    cells = (stamps[-1] - stamps[0]) / dt * max(len(timelines), 1)
    if cells > MAX_CLOCK_CELLS:
        k = int(np.argmax(np.diff(stamps))) if len(stamps) > 1 else 0
        raise HerdInputError(f'data time spans {stamps[-1] - stamps[0]:.0f} s, too long for '
                             f'one herd clock at dt {dt:g} s; its largest jump is from '
                             f'{stamps[k]:.3f} to {stamps[min(k + 1, len(stamps) - 1)]:.3f} s '
                             f'(a wrong stamp, or two recordings: split the file)')
    return tick_grid(stamps[0], stamps[-1], dt)


def raw_fixes_by_agent(fixes: pd.DataFrame, datum, agents, enu=None) -> dict:
    """{agent: (t (K,), xy (K, 2))}: each agent's raw position fixes in ENU (status not
    NO_FIX, finite), in stamp order: what a user without a filter has (the "last raw fix"
    baseline of the skill tables); ``enu`` the rows' (east, north) if already computed."""
    e, n = fixes_enu(fixes, datum) if enu is None else enu
    t = fixes['time'].to_numpy(float)
    status = fixes['status'].to_numpy(int) if 'status' in fixes else np.zeros(len(t), int)
    ok = (status != STATUS_NO_FIX) & np.isfinite(t) & np.isfinite(e) & np.isfinite(n)
    ids, uniques = pd.factorize(fixes['agent'].to_numpy(dtype=object))
    codes = pd.Index(list(agents)).get_indexer(uniques)[ids] if len(ids) else ids
    rows = np.flatnonzero(ok & (codes >= 0))
    rows = rows[np.lexsort((t[rows], codes[rows]))]
    bounds = np.searchsorted(codes[rows], np.arange(len(agents) + 1))
    return {a: (t[rows[bounds[i]:bounds[i + 1]]],
                np.column_stack([e[rows[bounds[i]:bounds[i + 1]]],
                                 n[rows[bounds[i]:bounds[i + 1]]]]))
            for i, a in enumerate(agents)}


def _slice(traj: HerdTrajectory, start: int, stop: int) -> HerdTrajectory:
    meta = {k: (v[start:stop].copy() if isinstance(v, np.ndarray) else v)
            for k, v in traj.meta.items()}
    return HerdTrajectory(traj.times[start:stop].copy(), list(traj.agents),
                          traj.positions[start:stop].copy(), traj.run, meta)


def _summary(counter: dict) -> str:
    return ', '.join(f'{k} {v}' for k, v in counter.items() if v)


def collar_spans(traj: HerdTrajectory) -> dict:
    """Per agent: (first tick, last tick, ticks with a position) of its track on the clock,
    times relative to the clock's start (s); (nan, nan, 0) for an agent never seen."""
    out = {}
    t0 = traj.times[0] if len(traj.times) else 0.0
    for i, a in enumerate(traj.agents):
        have = np.flatnonzero(np.isfinite(traj.positions[:, i, 0]))
        if len(have):
            out[a] = (float(traj.times[have[0]] - t0), float(traj.times[have[-1]] - t0),
                      int(len(have)))
        else:
            out[a] = (np.nan, np.nan, 0)
    return out


def refusal_runs(raw_fixes: dict, timelines: dict, t0: float = 0.0) -> dict:
    """Per agent, its longest run of consecutive fixes (its fixes with a position, in stamp
    order: :func:`raw_fixes_by_agent`) that its track did not take (no state at the fix's
    stamp in ``timelines``: refused, not yet confirmed, or out of order): ``(fixes, from_s,
    to_s)``, the times of the run's first and last fix relative to ``t0``; ``(0, nan,
    nan)`` when the track took every fix. A run longer than ``stale_after`` is a stretch
    with no rows in the track file (the collar is stale), and a fix after it is scored
    against its pose from before
    (:func:`~herd_ros.ingest.tracking_score.ingest_tracking_score`)."""
    out = {}
    for a, (t, _) in raw_fixes.items():
        t = np.asarray(t, dtype=float)
        took = taken(timelines[a], t) if a in timelines else np.zeros(len(t), bool)
        edges = np.diff(np.r_[0, (~took).astype(np.int8), 0])
        starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
        if not len(starts):
            out[a] = (0, np.nan, np.nan)
            continue
        k = int(np.argmax(ends - starts))
        out[a] = (int(ends[k] - starts[k]), float(t[starts[k]] - t0),
                  float(t[ends[k] - 1] - t0))
    return out


def format_refusal_runs(runs: dict, stale_after: float, shown: int = 5) -> str:
    """One line on the collars whose longest refused run outlasted ``stale_after`` (the
    ``shown`` longest), or '' when none did."""
    long = {a: r for a, r in runs.items() if r[0] and r[2] - r[1] > stale_after}
    if not long:
        return ''
    order = sorted(long, key=lambda a: -(long[a][2] - long[a][1]))
    parts = [f'{a} {long[a][0]} fixes from {long[a][1] / 3600:.2f} h for '
             f'{(long[a][2] - long[a][1]) / 60:.0f} min' for a in order[:shown]]
    more = f' and {len(order) - shown} more' if len(order) > shown else ''
    return (f'refused runs longer than stale_after ({stale_after:g} s: the collar has no '
            f'rows in the track file through them): ' + '; '.join(parts) + more)


def format_counters(counters: dict, spans: dict | None = None) -> str:
    """A small table of per-agent counters (rows: agents, columns: :data:`COUNTERS`), with
    each agent's span on the clock (:func:`collar_spans`: from, to in hours, ticks with a
    position) when ``spans`` is given."""
    names = list(COUNTERS) + (['rejected_future'] if any(
        c.get('rejected_future') for c in counters.values()) else [])
    short = [c.replace('rejected_', '') for c in names]
    width = max([len('agent')] + [len(a) for a in counters])
    extra = ['from_h', 'to_h', 'ticks'] if spans is not None else []
    lines = ['  '.join([f'{"agent":<{width}}'] + [f'{s:>8}' for s in short + extra])]
    for agent, c in counters.items():
        row = [f'{agent:<{width}}'] + [f'{c.get(k, 0):>8}' for k in names]
        if spans is not None:
            lo, hi, n = spans.get(agent, (np.nan, np.nan, 0))
            row += [f'{lo / 3600:>8.2f}', f'{hi / 3600:>8.2f}', f'{n:>8}']
        lines.append('  '.join(row))
    return '\n'.join(lines)


#: above this many collars ``herd-ros ingest`` prints only the collars that lost the most
#: fixes (the whole table goes to a CSV beside the output)
PRINTED_COLLARS = 30


def collar_table(counters: dict, spans: dict | None = None, fits: dict | None = None,
                 refusals: dict | None = None):
    """Per collar, everything the ingest says of it, as a DataFrame (rows: collars): the
    :data:`COUNTERS` (accepted and each rejection reason), its span on the clock
    (:func:`collar_spans`: from_h, to_h, ticks), its longest run of refused fixes
    (:func:`refusal_runs`: refused_run_fixes, refused_run_from_h, refused_run_min) and its
    last fitted motion model (model, tau_v_s, D_m2_s, speed_ms, fix_std_m, fixes_fitted)."""
    import pandas as pd
    rows = []
    for agent, c in counters.items():
        row = {'agent': agent, **{k: int(c.get(k, 0)) for k in COUNTERS}}
        if c.get('rejected_future'):
            row['rejected_future'] = int(c['rejected_future'])
        if spans is not None:
            lo, hi, n = spans.get(agent, (np.nan, np.nan, 0))
            row.update(from_h=lo / 3600, to_h=hi / 3600, ticks=int(n))
        if refusals is not None:
            k, lo, hi = refusals.get(agent, (0, np.nan, np.nan))
            row.update(refused_run_fixes=int(k), refused_run_from_h=lo / 3600,
                       refused_run_min=(hi - lo) / 60)
        f = (fits or {}).get(agent)
        if fits is not None:
            row.update(model=f.model if f is not None else 'prior',
                       tau_v_s=f.velocity_tau if f is not None else np.nan,
                       D_m2_s=f.diffusion if f is not None else np.nan,
                       speed_ms=f.speed_std if f is not None else np.nan,
                       fix_std_m=f.position_std if f is not None else np.nan,
                       fix_std_x_hdop=bool(f is not None and f.hdop),
                       fixes_fitted=f.n_fixes if f is not None else 0)
        rows.append(row)
    return pd.DataFrame(rows)


def lost_most(counters: dict, k: int) -> dict:
    """The ``k`` collars of ``counters`` with the most fixes not accepted (any reason but
    ``reinitialised``), in the table's order."""
    lost = {a: sum(v for key, v in c.items() if key.startswith('rejected_'))
            for a, c in counters.items()}
    keep = set(sorted(lost, key=lambda a: -lost[a])[:k])
    return {a: c for a, c in counters.items() if a in keep}


def format_motion_fits(fits: dict) -> str:
    """A small table of each collar's last fitted motion model: the model chosen (the IOU
    where it is the likelier by AIC and the closer one-step predictor, else the random walk),
    τ_v (s), the long-run diffusion D (m²/s per axis), the speed std (m/s per axis;
    ``cv end`` for a fit at the constant-velocity end, where it is not defined), the fix std
    σ_m (m; ``given`` where the fixes carried a covariance; ``× HDOP`` where a fix's std is
    σ_m times its HDOP) and the fixes fitted; ``prior`` for a collar with too few fixes to
    fit."""
    width = max([len('agent')] + [len(a) for a in fits])
    lines = [f'{"agent":<{width}}  {"motion":>6}  {"tau_v_s":>9}  {"D_m2_s":>9}  '
             f'{"speed_ms":>8}  {"fix_std_m":>9}  {"fixes":>5}']
    for agent, f in fits.items():
        if f is None:
            lines.append(f'{agent:<{width}}  {"prior":>6}')
            continue
        std = f'{f.position_std:9.2f}' if np.isfinite(f.position_std) else f'{"given":>9}'
        speed = f'{f.speed_std:8.3g}' if np.isfinite(f.speed_std) else f'{"cv end":>8}'
        lines.append(f'{agent:<{width}}  {f.model:>6}  {f.velocity_tau:9.3g}  '
                     f'{f.diffusion:9.3g}  {speed}  {std}  {f.n_fixes:>5}'
                     + ('  × HDOP' if f.hdop else ''))
    return '\n'.join(lines)
