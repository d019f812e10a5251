"""Tracking quality on real herds (issue 25): the causal track against the last raw fix.

The shipped real herds (19 baboons, 1 h of 1 Hz GPS; 20 steers, 72 h of RTLS) are seen
through duty-cycled collars with real-collar faults
(:func:`herd_ros.synthesis.collar_errors.duty_cycle_recorded_fixes`: fixes every 30-300 s
taken from the recording with its own noise, silences, late starts, early ends, bursts of
3-10 fixes 0.3-3 km off, duplicated stamps), and the synthetic collared cows
(:func:`simulate_cow_herd` 4 cows × 3 days through ``CollarErrorModel.real_collar``, fixes
every 30-300 s). Each goes through the offline ingest with default options
(``trajectory_from_fixes`` on the clock of ``track_dt``, what ``herd-ros ingest FILE -o
OUT`` runs) and is scored with
:mod:`herd_ros.ingest.tracking_score`: at every fix, where the causal track said the animal
was just before it against the last raw fix before it, distances to the fix (m). Two
tracks: each collar's own ("collar": its state after the last accepted fix, predicted to
the fix, what its odometry said) and the herd clock's last pose before the fix ("clock",
the track file at ``herd-ros ingest``'s default clock step, :func:`track_dt`, which lags
by up to a step). Scored
fixes: those not part of an injected burst ("genuine": a burst fix is not where the animal
is); "all" scores every fix. Also the distance to the recording itself ("dense"): at every
recorded position of an active collar, the clock's last pose before it against the last
kept raw fix before it. Fix by fix (:func:`paired`): the share of fixes at which the track
is the closer, with its Wilson interval, and the median paired difference.

    .venv/bin/python test/bench/bench_tracking.py [--seeds N] [--herds baboons,steers,cows]
        [--recording FILE ...] [--motion-model auto|fit|fixed] [--no-predictors]
        [--json FILE]

``--recording FILE`` (repeatable) scores a recording of your own the same way, beside the
shipped herds or alone (``--herds ''``): a trajectory CSV of planar fixes
(``time,agent,x,y`` in metres, RTLS/UWB) or any fix file ``herd-ros ingest`` reads (GPS
CSV, Movebank CSV, GPX, rosbag2), GPS taken to ENU metres about its first valid fix. It is
seen through the same duty-cycled collars (the recording's own error kept), named by its
file name.

Then, on the real herds, simple causal predictors fed only the genuine fixes
(:func:`simple_predictors`): the bound the recordings set on any one-step predictor of
those families, the filter's among them.
"""
import argparse
import functools
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
sys.path.insert(0, str(ROOT))

from herd_ros.ingest.geodesy import geodetic_to_enu  # noqa: E402
from herd_ros.ingest.pipeline import (choose_datum, fixes_enu, load_fixes,  # noqa: E402
                                      planar_fixes, track_dt, trajectory_from_fixes,
                                      valid_fix_mask)
from herd_ros.ingest.tracking_score import (STATS, collar_track_distances,  # noqa: E402
                                            next_fix_distances, paired, summarise)
from herd_ros.synthesis.collar_errors import (CollarErrorModel,  # noqa: E402
                                              duty_cycle_recorded_fixes,
                                              simulate_collar_fixes)

INTERVALS = (30.0, 300.0)


def recorded_baboons():
    fixes = load_fixes(ROOT / 'bags' / 'baboons_1h')
    ok = np.isfinite(fixes[['lat', 'lon']].to_numpy()).all(axis=1)
    fixes = fixes[ok]
    lat0, lon0 = fixes['lat'].iloc[0], fixes['lon'].iloc[0]
    e, n, _ = geodetic_to_enu(fixes['lat'].to_numpy(), fixes['lon'].to_numpy(),
                              np.zeros(len(fixes)), lat0, lon0, 0.0)
    return pd.DataFrame({'time': fixes['time'].to_numpy(), 'agent': fixes['agent'].to_numpy(),
                         'x': e, 'y': n})


def recorded_steers():
    return pd.read_csv(ROOT / 'bags' / 'steers_72h.csv')[['time', 'agent', 'x', 'y']]


#: recordings given with ``--recording``: {name: path}
RECORDINGS: dict = {}


def recorded_file(path) -> pd.DataFrame:
    """A recording of one's own (``--recording``) as ``time, agent, x, y`` (m): a
    trajectory CSV of planar fixes as it is; a fix file (:func:`load_fixes`) without its
    NO_FIX and NaN fixes, in ENU about its first valid fix (:func:`choose_datum`)."""
    from herd_ros.data_sources import is_trajectory_csv, planar_fixes_from_runs
    path = Path(path)
    if is_trajectory_csv(path):
        fixes = planar_fixes_from_runs(path)
        x, y = fixes['east'].to_numpy(float), fixes['north'].to_numpy(float)
    else:
        fixes = load_fixes(path)
        fixes = fixes[valid_fix_mask(fixes)].reset_index(drop=True)
        x, y = fixes_enu(fixes, choose_datum(fixes))
    return pd.DataFrame({'time': fixes['time'].to_numpy(float),
                         'agent': fixes['agent'].astype(str).to_numpy(), 'x': x, 'y': y})


@functools.lru_cache(maxsize=None)
def recorded(herd):
    """A real herd's recording, shipped or given with ``--recording`` (read once)."""
    if herd in RECORDINGS:
        return recorded_file(RECORDINGS[herd])
    return recorded_baboons() if herd == 'baboons' else recorded_steers()


@functools.lru_cache(maxsize=None)
def duty_cycled(herd, seed):
    """A real herd's recording seen through the duty-cycled collars, one seed (made once:
    the tracking and :func:`simple_predictors` score the same fixes)."""
    model = CollarErrorModel.real_collar(fix_interval_range=INTERVALS)
    return duty_cycle_recorded_fixes(recorded(herd), seed=seed, model=model)


def real_case(herd, seed, **ingest):
    fixes = duty_cycled(herd, seed)
    counts = fixes.groupby('agent')['time'].transform('size')
    fixes = fixes[counts >= 5].reset_index(drop=True)     # collars left with a few fixes
    t0 = time.perf_counter()
    planar = planar_fixes(fixes)
    traj = trajectory_from_fixes(planar, ingest.pop('dt', None) or track_dt(planar), **ingest)
    return fixes, traj, time.perf_counter() - t0, recorded(herd)


def cows_case(seed, **ingest):
    from herd_ros.synthesis.cow_scenario import simulate_cow_herd
    truth = simulate_cow_herd(n_cows=4, duration_s=3 * 86400.0, dt=10.0, seed=seed)
    model = CollarErrorModel.real_collar(fix_interval_range=INTERVALS)
    raw = simulate_collar_fixes(truth, seed=seed, model=model)
    raw = raw[raw['status'] == 0].reset_index(drop=True)
    datum = raw.attrs['datum']
    t0 = time.perf_counter()
    traj = trajectory_from_fixes(raw, ingest.pop('dt', None) or track_dt(raw), datum=datum,
                                 **ingest)
    elapsed = time.perf_counter() - t0
    e, n, _ = geodetic_to_enu(raw['lat'].to_numpy(), raw['lon'].to_numpy(),
                              raw['alt'].fillna(datum[2]).to_numpy(), *datum)
    fixes = pd.DataFrame({'time': raw['time'], 'agent': raw['agent'], 'x': e, 'y': n,
                          'burst': raw['burst'], 'duplicate': raw['duplicate']})
    tt = np.repeat(truth.times, truth.n_agents)
    dense = pd.DataFrame({'time': tt, 'agent': np.tile(truth.agents, truth.n_steps),
                          'x': truth.positions[..., 0].ravel(),
                          'y': truth.positions[..., 1].ravel()})
    return fixes, traj, elapsed, dense


def dense_distances(fixes, traj, dense):
    """(d_track, d_raw) at every recorded position of a collar between its first and last
    kept fix: last track pose before it, and last kept raw fix before it."""
    out_t, out_r = [], []
    for i, a in enumerate(traj.agents):
        g = fixes[fixes['agent'].astype(str) == a].sort_values('time')
        d = dense[dense['agent'].astype(str) == a]
        d = d[(d['time'] > g['time'].iloc[0]) & (d['time'] <= g['time'].iloc[-1])]
        # the dense positions become "targets", the kept fixes their predecessors
        probe = pd.concat([g[['time', 'agent', 'x', 'y']].assign(target=False),
                           d[['time', 'agent', 'x', 'y']].assign(target=True, time=d['time']
                                                                 + 1e-6)])
        probe = probe.sort_values('time', kind='stable')
        t = probe['time'].to_numpy(float)
        z = probe[['x', 'y']].to_numpy(float)
        tg = probe['target'].to_numpy()
        kept_t, kept_z = t[~tg], z[~tg]
        k = np.searchsorted(kept_t, t[tg], side='left') - 1
        raw = np.where((k >= 0)[:, None], kept_z[np.maximum(k, 0)], np.nan)
        from herd_ros.ingest.tracking_score import last_pose_before
        track = last_pose_before(traj.times, traj.positions[:, i], t[tg])
        ok = np.isfinite(raw).all(axis=1) & np.isfinite(track).all(axis=1)
        out_t.append(np.hypot(*(track[ok] - z[tg][ok]).T))
        out_r.append(np.hypot(*(raw[ok] - z[tg][ok]).T))
    return np.concatenate(out_t), np.concatenate(out_r)


def fmt(s):
    return (f"{s['median']:8.2f} {s['p90']:8.2f} {s['p99']:8.1f} {s['rms']:8.1f} "
            f"{100 * s['beyond_100m']:7.2f}%  n={s['n']}")


#: what is scored: each collar's causal track (its state after the last accepted fix
#: before each fix, predicted to the fix: what its odometry said) and the herd clock's
#: last pose before the fix (``/herd/poses`` at the clock step of the default ingest)
TRACKS = ('collar', 'clock')


def run(herds, seeds, dense=True, **ingest):
    """{herd: {track: {targets: {'track': summary, 'last_raw_fix': summary}}, 'ingest_s'}}
    over ``seeds`` seeds (scores pooled)."""
    results = {}
    for herd in herds:
        acc = {(w, k): ([], []) for w in TRACKS for k in ('genuine', 'all', 'dense')}
        secs = 0.0
        for seed in range(seeds):
            if herd == 'cows':
                fixes, traj, el, rec = cows_case(seed, **ingest)
            else:
                fixes, traj, el, rec = real_case(herd, seed, **ingest)
            secs += el
            for key, mask in (('genuine', ~fixes['burst'].to_numpy()), ('all', None)):
                for w, (d_t, d_r) in (
                        ('collar', collar_track_distances(fixes, traj.meta['timelines'],
                                                          mask)),
                        ('clock', next_fix_distances(fixes, traj.times, traj.positions,
                                                     traj.agents, mask))):
                    acc[w, key][0].append(d_t)
                    acc[w, key][1].append(d_r)
            if dense:
                d_t, d_r = dense_distances(fixes, traj, rec)
                acc['clock', 'dense'][0].append(d_t)
                acc['clock', 'dense'][1].append(d_r)
        out = {w: {} for w in TRACKS}
        for (w, k), v in acc.items():
            if v[0]:
                d_t, d_r = np.concatenate(v[0]), np.concatenate(v[1])
                out[w][k] = {'track': summarise(d_t), 'last_raw_fix': summarise(d_r),
                             'paired': paired(d_t, d_r)}
        out['ingest_s'] = secs / seeds
        out['dt'] = float(traj.meta['dt'])
        results[herd] = out
    return results


def wins(r) -> dict:
    """Per statistic: the track's value is at most the last raw fix's."""
    return {s: r['track'][s] <= r['last_raw_fix'][s] for s in STATS}


#: the simple causal predictors of :func:`simple_predictors`: exponential smoothing of the
#: fixes (weight α on the newest) and the last fix plus a share β of its velocity carried
#: for a correlation time τ (s), the velocity from the last two fixes
SMOOTHING = (0.95, 0.9, 0.8)
CARRY = ((0.5, 10.0), (0.5, 30.0), (1.0, 30.0), (0.5, 120.0))


def simple_predictors(fixes_by_seed) -> dict:
    """How the simple causal predictors do on the genuine fixes of a herd's duty-cycled
    collars (every seed pooled): each predictor sees only the genuine fixes (it is told
    which are bursts: an oracle on outliers no filter has), and at each genuine fix after
    a collar's second predicts it from those before. {name: summarise(distances)}: the
    last genuine fix, :data:`SMOOTHING` and :data:`CARRY`. What they show: whether any
    predictor of these families, the Kalman filter's one-step predictions among them (its
    gain is a smoothing weight, its velocity a carry), can beat the last fix at all."""
    from scipy.signal import lfilter
    out = {}
    for fixes in fixes_by_seed:
        g = fixes[~fixes['burst'].to_numpy()]
        for _, c in g.groupby('agent', sort=False):
            c = c.sort_values('time', kind='stable')
            t = c['time'].to_numpy(float)
            z = c[['x', 'y']].to_numpy(float)
            keep = np.concatenate([[True], np.diff(t) > 0])
            t, z = t[keep], z[keep]
            if len(t) < 3:
                continue
            target, last = z[2:], z[1:-1]
            d_prev, d_next = np.diff(t)[:-1], np.diff(t)[1:]
            v = (z[1:-1] - z[:-2]) / d_prev[:, None]
            preds = {'last genuine fix': last}
            for a in SMOOTHING:
                s = np.column_stack([lfilter([a], [1.0, a - 1.0], z[:, j],
                                             zi=[(1.0 - a) * z[0, j]])[0] for j in (0, 1)])
                preds[f'smoothing a={a:g}'] = s[1:-1]
            for beta, tau in CARRY:
                reach = tau * (1.0 - np.exp(-d_next / tau))
                preds[f'carry b={beta:g} tau={tau:g} s'] = last + beta * v * reach[:, None]
            for name, p in preds.items():
                out.setdefault(name, []).append(np.hypot(*(target - p).T))
    return {name: summarise(np.concatenate(d)) for name, d in out.items()}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--seeds', type=int, default=3)
    ap.add_argument('--herds', default='baboons,steers,cows',
                    help="shipped herds, comma-separated ('' for none)")
    ap.add_argument('--recording', action='append', default=[], metavar='FILE',
                    help='also a recording of your own (repeatable): a trajectory CSV of '
                         'planar fixes (time,agent,x,y) or a GPS file herd-ros ingest reads')
    ap.add_argument('--motion-model', default='auto', choices=('auto', 'fit', 'fixed'))
    ap.add_argument('--no-dense', action='store_true')
    ap.add_argument('--json', default=None, help='also write the results here')
    ap.add_argument('--no-predictors', action='store_true',
                    help='skip the simple causal predictors on the real herds\' genuine '
                         'fixes (simple_predictors)')
    args = ap.parse_args(argv)
    herds = [h for h in args.herds.split(',') if h]
    for path in args.recording:
        if not Path(path).exists():
            ap.error(f'--recording {path}: no such file or directory')
        name = Path(path).name
        while name in herds:
            name += "'"
        RECORDINGS[name] = path
        herds.append(name)
    if not herds:
        ap.error('nothing to score: give --herds or --recording')
    res = run(herds, args.seeds, dense=not args.no_dense, motion_model=args.motion_model)
    print(f'tracking on duty-cycled collars (fixes every {INTERVALS[0]:g}-{INTERVALS[1]:g} s, '
          f'real-collar faults), {args.seeds} seeds, motion model: {args.motion_model}; '
          f'distance to the next fix (m)')
    print(f'{"herd / track / scored":34s} {"":14s}   median      p90      p99      RMS   >100 m')
    for herd, r in res.items():
        for w in TRACKS:
            for key in ('genuine', 'all', 'dense'):
                if key not in r[w]:
                    continue
                label = f'{herd} / {w}' + (f' ({r["dt"]:g} s)' if w == 'clock' else '')
                for who in ('track', 'last_raw_fix'):
                    print(f'{label + " / " + key:34s} {who:14s} {fmt(r[w][key][who])}')
        pg = r['collar']['genuine']['paired']
        print(f'{herd}: fix by fix (genuine fixes), the collar track is the closer at '
              f'{100 * pg["closer"]:.1f} % [{100 * pg["closer_ci"][0]:.1f}, '
              f'{100 * pg["closer_ci"][1]:.1f}] of the fixes where they differ '
              f'({100 * pg["ties"]:.0f} % ties within 1 mm); median d_track - d_raw '
              f'{pg["median_difference"]:+.3f} m')
        for w, name in (('collar', 'collar track'), ('clock', 'track file')):
            lost = [s for s, v in wins(r[w]['genuine']).items() if not v]
            print(f'{herd}: {name} vs last raw fix (genuine fixes): '
                  + ('beats or ties it on every statistic' if not lost
                     else f'loses on {", ".join(lost)}'))
        print(f'{herd}: ingest {r["ingest_s"]:.2f} s per run')
    if not args.no_predictors:
        print('simple causal predictors, fed only the genuine fixes (told which are bursts), '
              'at each genuine fix after a collar\'s second (m)')
        for herd in res:
            if herd == 'cows':
                continue
            table = simple_predictors([duty_cycled(herd, seed) for seed in range(args.seeds)])
            res[herd]['simple_predictors'] = table
            for name, summary in table.items():
                print(f'{herd + " / " + name:49s} {fmt(summary)}')
    if args.json:
        import json
        Path(args.json).write_text(json.dumps(res, indent=1))
    print('reproduce with: .venv/bin/python test/bench/bench_tracking.py')
    return 0


if __name__ == '__main__':
    sys.exit(main())
