"""How well a causal track knows where an animal is, against the last raw fix.

The measure of issue 25: at every fix of a collar, where did the track say the animal was
just before that fix arrived (its last pose strictly before the fix's stamp), and where was
the last raw fix before it (what a user has with no filter at all)? Both are scored by their
distance to the new fix::

    d_track(k) = ‖ track(t⁻_k) − z_k ‖,   d_raw(k) = ‖ z_{k−1} − z_k ‖

summarised by the median, 90th and 99th percentiles, the RMS and the share beyond 100 m
(:func:`summarise`), and fix by fix (:func:`paired`): the share of fixes at which the track
was the closer of the two, with its Wilson interval, and the median of
``d_track − d_raw``. The two views can disagree where the distances have a point mass: the
steers' recording moves in steps of exactly 1.00 m (a fifth of its 4-8 s steps), so one raw
next-fix distance in eight is 1.00 ± 0.02 m, right at the median; a track a few centimetres
off the last fix spreads that spike over both sides and can come out a few centimetres
behind on the median of the distances while being the closer one as often as not.

A fix is scored only where both exist (a collar's first fix has no predecessor; the track
has no pose before its first accepted fix). The ``targets`` mask picks which fixes are
scored (e.g. leave out the fixes of an injected outlier burst, which are not where the
animal is); the predecessors are always every raw fix, bursts included, as a user without
a filter would have them.

Plain numpy; used by the tracking benchmark and its tests.
"""
from __future__ import annotations

import numpy as np
import pandas as pd

#: The share of distances beyond this many metres is reported.
FAR_M = 100.0
STATS = ('median', 'p90', 'p99', 'rms', 'beyond_100m')


def summarise(d) -> dict:
    """Median, p90, p99, RMS (m) and share (fraction) beyond :data:`FAR_M` of distances."""
    d = np.asarray(d, dtype=float)
    d = d[np.isfinite(d)]
    if not len(d):
        return {k: float('nan') for k in STATS} | {'n': 0}
    return {'median': float(np.median(d)), 'p90': float(np.percentile(d, 90)),
            'p99': float(np.percentile(d, 99)), 'rms': float(np.sqrt(np.mean(d ** 2))),
            'beyond_100m': float(np.mean(d > FAR_M)), 'n': int(len(d))}


def paired(d_track, d_raw) -> dict:
    """Fix-by-fix comparison of two aligned distance arrays (NaN pairs left out):
    ``closer`` the share of fixes where the track is strictly closer among those where the
    two differ by more than 1 mm, ``closer_ci`` its Wilson 95 % interval (a sign test:
    the interval excludes 0.5 when one is closer significantly more often),
    ``median_difference`` the median of ``d_track − d_raw`` (m), ``n`` the pairs,
    ``ties`` the share within 1 mm."""
    from herd_ros.report.intervals import wilson_interval
    a = np.asarray(d_track, dtype=float)
    b = np.asarray(d_raw, dtype=float)
    ok = np.isfinite(a) & np.isfinite(b)
    diff = a[ok] - b[ok]
    differ = np.abs(diff) > 1e-3
    k, m = int(np.sum(diff[differ] < 0)), int(np.sum(differ))
    return {'closer': k / m if m else float('nan'), 'closer_ci': list(wilson_interval(k, m)),
            'median_difference': float(np.median(diff)) if len(diff) else float('nan'),
            'n': int(len(diff)), 'ties': float(np.mean(~differ)) if len(diff) else float('nan')}


def last_pose_before(times, positions, stamps):
    """The last finite pose of a track (``times`` (T,), ``positions`` (T, 2)) strictly
    before each stamp; NaN where there is none."""
    ok = np.isfinite(positions).all(axis=1)
    t, p = np.asarray(times, float)[ok], positions[ok]
    k = np.searchsorted(t, stamps, side='left') - 1
    out = np.full((len(stamps), 2), np.nan)
    have = k >= 0
    out[have] = p[k[have]]
    return out


def _distances(fixes: pd.DataFrame, agents, track_before, targets=None
               ) -> tuple[np.ndarray, np.ndarray]:
    """(d_track, d_raw) at each scored fix; ``track_before(i, agent, stamps)`` gives agent
    i's track just before each of its fix stamps ((K, 2), NaN where it has none)."""
    targets = np.ones(len(fixes), dtype=bool) if targets is None else np.asarray(targets)
    out_t, out_r = [], []
    agent_col = fixes['agent'].astype(str).to_numpy()
    for i, a in enumerate(agents):
        rows = np.flatnonzero(agent_col == str(a))
        g = fixes.iloc[rows]
        order = np.argsort(g['time'].to_numpy(float), kind='stable')
        t = g['time'].to_numpy(float)[order]
        d_t, d_r = _agent_distances(t, g[['x', 'y']].to_numpy(float)[order],
                                    track_before(i, a, t), targets[rows][order])
        out_t.append(d_t)
        out_r.append(d_r)
    if not out_t:
        return np.zeros(0), np.zeros(0)
    return np.concatenate(out_t), np.concatenate(out_r)


def _last_raw_before(t, z, stamps) -> np.ndarray:
    """The last of an agent's fixes (t (K,) in stamp order, z (K, 2)) strictly before each
    stamp (a duplicated stamp is not "before" its twin); NaN where there is none."""
    k = np.searchsorted(t, stamps, side='left') - 1
    return np.where((k >= 0)[:, None], z[np.maximum(k, 0)], np.nan)


def _agent_distances(t, z, track, targets) -> tuple[np.ndarray, np.ndarray]:
    """(d_track, d_raw) of one agent's fixes (t (K,) in stamp order, z (K, 2)) given its
    track just before each (K, 2) and which fixes are scored (K,)."""
    raw = _last_raw_before(t, z, t)
    ok = targets & np.isfinite(raw).all(axis=1) & np.isfinite(track).all(axis=1)
    return np.hypot(*(track[ok] - z[ok]).T), np.hypot(*(raw[ok] - z[ok]).T)


def next_fix_distances(fixes: pd.DataFrame, track_times, track_positions, agents,
                       targets=None) -> tuple[np.ndarray, np.ndarray]:
    """(d_track, d_raw) at each scored fix (see the module docstring).

    Args:
        fixes: ``time, agent, x, y`` in the track's frame (metres).
        track_times: (T,) the track's clock; ``track_positions`` (T, N, 2), NaN where the
            track has no pose; ``agents`` its N agent ids.
        targets: boolean mask over ``fixes`` rows that may be scored (default all).
    """
    return _distances(fixes, agents, lambda i, a, t: last_pose_before(
        track_times, track_positions[:, i], t), targets)


def taken(timeline, stamps) -> np.ndarray:
    """Which of a collar's fix ``stamps`` its track took: a state of ``timeline`` (one per
    accepted fix) at the stamp."""
    states = np.asarray(timeline.t, dtype=float)
    stamps = np.asarray(stamps, dtype=float)
    if not len(states):
        return np.zeros(len(stamps), bool)
    return states[np.minimum(np.searchsorted(states, stamps), len(states) - 1)] == stamps


def collar_track_before(timeline, stamps, eps: float = 1e-6):
    """A collar's causal track just before each stamp: its state after the last accepted
    fix strictly before the stamp, predicted to ``stamp − eps`` with its motion model
    (:meth:`~herd_ros.ingest.herd_clock.StateTimeline.at`; NaN before its first fix or
    when stale). This is what the collar's odometry said when the fix arrived."""
    stamps = np.asarray(stamps, dtype=float)
    x, _, _, _ = timeline.at(stamps - eps)
    return x[:, :2]


def collar_track_distances(fixes: pd.DataFrame, timelines: dict, targets=None
                           ) -> tuple[np.ndarray, np.ndarray]:
    """(d_track, d_raw) as :func:`next_fix_distances`, the track being each collar's
    causal track (:func:`collar_track_before`) rather than the herd clock's poses."""
    return _distances(fixes, list(timelines),
                      lambda i, a, t: collar_track_before(timelines[a], t), targets)


def tracking_table(fixes: pd.DataFrame, track_times, track_positions, agents,
                   targets=None) -> dict:
    """{'track': summarise(d_track), 'last_raw_fix': summarise(d_raw)} of
    :func:`next_fix_distances`."""
    d_t, d_r = next_fix_distances(fixes, track_times, track_positions, agents, targets)
    return {'track': summarise(d_t), 'last_raw_fix': summarise(d_r)}


#: the most fixes :func:`ingest_tracking_score` scores (beyond, every k-th of each collar)
MAX_SCORED = 50_000


def ingest_tracking_score(raw_fixes: dict, timelines: dict,
                          max_scored: int = MAX_SCORED, clock=None) -> dict:
    """The measure on an ingested file itself, as ``herd-ros ingest`` reports it.

    Args:
        raw_fixes: {agent: (t (K,), xy (K, 2))}, each collar's valid fixes in stamp order
            (:func:`herd_ros.ingest.pipeline.raw_fixes_by_agent`).
        timelines: {agent: StateTimeline}, each collar's causal filter states, one per
            accepted fix (at its stamp).
        max_scored: above this many fixes, every k-th fix of each collar is scored
            (k the smallest that keeps them within it; ``stride`` in the tables): the
            statistics of 50 000 fixes, at a tenth of the cost of 360 000.
        clock: ``(times (T,), positions (T, N, 2), agents)`` of the written track (the
            herd clock, NaN where a collar has no pose), or None. Given, a third table
            ``file`` scores every valid fix against the clock's last finite pose before it,
            however old: what a user reading the track file gets (a collar that refuses its
            fixes for longer than ``stale_after`` has no rows there, so its last row is from
            before the refusals; the collar track is not scored while stale).

    Returns:
        ``{'every': table, 'accepted': table[, 'file': table]}``, each table ``{'track':
        summarise(d_track), 'last_raw_fix': summarise(d_raw), 'paired': paired(d_track,
        d_raw), 'eligible': fixes with a raw fix before them, 'stride': k}`` (a fix is
        scored where the track too has a pose before it: not while its collar is stale or
        its track not yet confirmed). ``every`` scores every valid fix, outliers
        included: the file does not say which fixes are outliers, and a burst's second
        fix is near its first, so bursts favour the last raw fix there. ``accepted``
        scores the fixes the filter took (a fix whose stamp is one of its collar's
        states), which leaves out the fixes it judged wrong and so favours the track.
        The truth lies between; the tracking benchmark scores the fixes known not to be
        injected outliers.
    """
    used = [a for a, (t, _) in raw_fixes.items() if a in timelines and len(t)]
    total = sum(len(raw_fixes[a][0]) for a in used)
    stride = max(1, -(-total // int(max_scored)))
    zs, raws, tracks, took, files = [], [], [], [], []
    column = {str(a): i for i, a in enumerate(clock[2])} if clock is not None else {}
    if clock is not None:
        # each tick's last tick with a finite pose, per collar (-1: none yet), made once
        ticks = np.asarray(clock[0], dtype=float)
        poses = np.asarray(clock[1], dtype=float)
        finite = np.isfinite(poses).all(axis=2)
        last = np.maximum.accumulate(np.where(finite, np.arange(len(ticks))[:, None], -1),
                                     axis=0)
    for a in used:
        t = np.asarray(raw_fixes[a][0], dtype=float)
        z = np.asarray(raw_fixes[a][1], dtype=float).reshape(-1, 2)
        pick = np.arange(0, len(t), stride)
        raws.append(_last_raw_before(t, z, t[pick]))
        zs.append(z[pick])
        tracks.append(collar_track_before(timelines[a], t[pick]))
        if clock is not None:                     # (stamps, collar column) for below
            files.append((t[pick], np.full(len(pick), column.get(str(a), -1))))
        took.append(taken(timelines[a], t[pick]))
    if used:
        z, raw, track = np.concatenate(zs), np.concatenate(raws), np.concatenate(tracks)
        took = np.concatenate(took)
    else:
        z = raw = track = np.zeros((0, 2))
        took = np.zeros(0, bool)
    has_raw = np.isfinite(raw).all(axis=1)
    ok = has_raw & np.isfinite(track).all(axis=1)
    d_track = np.hypot(*(track - z).T)
    d_raw = np.hypot(*(raw - z).T)
    out = {}
    tables = [('every', ok, d_track), ('accepted', ok & took, d_track)]
    if clock is not None:
        file = np.full((len(z), 2), np.nan)
        if files and len(ticks):
            stamps = np.concatenate([f[0] for f in files])
            col = np.concatenate([f[1] for f in files])
            k = np.searchsorted(ticks, stamps, side='left') - 1        # strictly before
            j = np.where((k >= 0) & (col >= 0), last[np.maximum(k, 0), np.maximum(col, 0)],
                         -1)
            file[j >= 0] = poses[j[j >= 0], col[j >= 0]]
        tables.append(('file', has_raw & np.isfinite(file).all(axis=1),
                       np.hypot(*(file - z).T)))
    for name, mask, d in tables:
        d_t, d_r = d[mask], d_raw[mask]
        out[name] = {'track': summarise(d_t), 'last_raw_fix': summarise(d_r),
                     'paired': paired(d_t, d_r),
                     'eligible': int(np.sum(has_raw & took if name == 'accepted'
                                            else has_raw)),
                     'stride': stride}
    return out


def format_ingest_tracking_score(score: dict) -> str:
    """Lines for :func:`ingest_tracking_score`'s tables (distances in metres)."""
    lines = ['tracking: at each fix, its distance (m) from the causal track just before it '
             'and from the last raw fix before it (no filter)',
             f'{"fixes scored":<24} {"":<13} {"median":>8} {"p90":>8} {"p99":>8} '
             f'{"RMS":>8} {">100 m":>7}']
    rows = [('every', 'every valid fix', 'collar track'),
            ('accepted', 'fixes accepted', 'collar track')]
    if 'file' in score:
        rows.append(('file', 'every valid fix', 'track file'))
    for name, label, track_label in rows:
        tab = score[name]
        for who, wl in (('track', track_label), ('last_raw_fix', 'last raw fix')):
            s = tab[who]
            lines.append(f'{label:<24} {wl:<13} {s["median"]:8.2f} {s["p90"]:8.2f} '
                         f'{s["p99"]:8.1f} {s["rms"]:8.1f} {100 * s["beyond_100m"]:6.2f}%')
            label = f'  (n {s["n"]} of {tab["eligible"]})'
        p = tab['paired']
        if np.isfinite(p['closer']):
            lines.append(f'{"":<24} the {track_label} is the closer at '
                         f'{100 * p["closer"]:.1f} % of the fixes where the two differ')
    stride = score['every'].get('stride', 1)
    lines.append('(n: the fixes scored, of those with a fix before them'
                 + (f' among every k-th fix of each collar, k = {stride}' if stride > 1
                    else '')
                 + '; the rest came while the collar was stale or its track not yet '
                 'confirmed)')
    if 'file' in score:
        lines += ['(track file: the last pose the written track holds before each fix, '
                  'however old: a collar',
                  ' that refuses its fixes for longer than stale_after has no rows until it '
                  'takes one again,',
                  ' so such a fix is scored against its pose from before the refusals, and '
                  'a burst it refused',
                  ' counts against it at each of its fixes)']
    return '\n'.join(lines)
