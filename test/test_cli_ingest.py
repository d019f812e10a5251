"""`herd-ros ingest`, `import` and `bag-info` in process, on small generated data."""
import numpy as np
import pandas as pd
import pytest

from herd_ros.cli.main import main
from herd_ros.ingest.geodesy import enu_to_geodetic
from herd_ros.trajectory import read_trajectory_csv

DATUM = (27.0153, -108.7937, 100.0)


@pytest.fixture
def gps_csv(tmp_path):
    rng = np.random.default_rng(0)
    rows = []
    for i in range(3):
        t = 1.7e9 + np.arange(300) + rng.uniform(0, 0.3, 300)
        e = 20 * i + 0.1 * np.arange(300) + rng.normal(0, 2, 300)
        n = -10 * i + rng.normal(0, 2, 300)
        lat, lon, _ = enu_to_geodetic(e, n, 0.0, *DATUM)
        alt = np.where(rng.random(300) < 0.2, np.nan, 100.0)
        rows.append(pd.DataFrame({'time': t, 'agent': f'cow_{i}', 'lat': lat, 'lon': lon,
                                  'alt': alt}))
    path = tmp_path / 'fixes.csv'
    pd.concat(rows).sort_values('time').to_csv(path, index=False, float_format='%.10f')
    return path


@pytest.mark.parametrize('smoother', ['none', 'rts', 'fir'])
def test_ingest_gps_csv(gps_csv, tmp_path, capsys, smoother):
    out = tmp_path / f'traj_{smoother}.csv'
    rc = main(['ingest', str(gps_csv), '-o', str(out), '--dt', '2', '--smoother', smoother,
               '--datum', ','.join(map(str, DATUM))])
    assert rc == 0
    text = capsys.readouterr().out
    assert 'datum: lat 27.015300000 lon -108.793700000' in text and 'cow_2' in text
    # the tracking measure on the file itself: every fix after a collar's first (299 of
    # each collar's 300) scored against the last raw fix; consecutive fixes with 2 m noise per
    # axis are 2√2 m apart per axis, a Rayleigh median of 2√2·√(2 ln 2) = 3.33 m
    lines = text.splitlines()
    first = next(i for i, line in enumerate(lines) if line.startswith('every valid fix'))
    track = float(lines[first].split()[5])
    raw = float(lines[first + 1].split()[7])
    # a new track starts on its second consistent fix: the second fix of each collar has
    # no track pose before it
    assert '(n 894 of 897)' in lines[first + 1]
    assert 3.0 < raw < 3.7 and track < raw
    # the written track scored as a user would (its last pose before each fix): only where
    # it is causal, without a smoother
    assert ('track file' in text) == (smoother == 'none')
    # per collar, what was kept and why anything was not: every input fix is counted once
    table = pd.read_csv(out.with_suffix('.collars.csv'))
    fixes = pd.read_csv(gps_csv)
    assert list(table['agent']) == ['cow_0', 'cow_1', 'cow_2']
    for _, row in table.iterrows():
        counted = row['accepted'] + sum(row[c] for c in table.columns
                                        if c.startswith('rejected_'))
        assert counted == (fixes['agent'] == row['agent']).sum()
    assert {'from_h', 'to_h', 'ticks', 'refused_run_fixes', 'refused_run_from_h',
            'refused_run_min'} <= set(table.columns)
    assert (table['refused_run_fixes'] <= table['rejected_gate'] + table['rejected_speed']
            + table['rejected_range'] + table['rejected_unconfirmed']
            + table['rejected_time']).all()
    (traj,) = read_trajectory_csv(out)           # uniform, complete: what `fit` needs
    assert traj.agents == ['cow_0', 'cow_1', 'cow_2'] and traj.dt == pytest.approx(2.0)
    assert traj.n_steps > 140
    # cow_1 walks east at 0.1 m/s from x = 20, y = -10
    t_rel = traj.times - 1.7e9
    tol = 3.0 if smoother != 'fir' else 4.0
    assert np.max(np.abs(traj.positions[20:, 1, 1] + 10)) < tol
    assert np.max(np.abs(traj.positions[20:, 1, 0] - (20 + 0.1 * t_rel[20:]))) < tol


def test_import_bag_info_and_ingest_bag(gps_csv, tmp_path, capsys):
    bag = tmp_path / 'cows_bag'
    assert main(['import', str(gps_csv), '-o', str(bag)]) == 0
    text = capsys.readouterr().out
    assert 'read 900 fixes of 3 agents (gps)' in text and '/herd/cow_0/fix' in text
    assert main(['bag-info', str(bag)]) == 0
    text = capsys.readouterr().out
    assert 'storage:  mcap' in text and 'messages: 900' in text
    out_bag, out_csv = tmp_path / 'a.csv', tmp_path / 'b.csv'
    assert main(['ingest', str(bag), '-o', str(out_bag), '--dt', '1']) == 0
    assert main(['ingest', str(gps_csv), '-o', str(out_csv), '--dt', '1']) == 0
    capsys.readouterr()
    (a,), (b,) = read_trajectory_csv(out_bag), read_trajectory_csv(out_csv)
    np.testing.assert_allclose(a.positions, b.positions, atol=1e-3)   # CSV rounding only
    sq = tmp_path / 'sq_bag'
    assert main(['import', str(gps_csv), '-o', str(sq), '--storage', 'sqlite3']) == 0
    assert main(['bag-info', str(sq)]) == 0
    assert 'storage:  sqlite3' in capsys.readouterr().out


@pytest.mark.parametrize('argv, message', [
    (['ingest', '{missing}', '-o', '{out}', '--dt', '1'], 'no such file'),
    (['ingest', '{bad}', '-o', '{out}', '--dt', '1'], 'line 3: lat'),
    (['ingest', '{good}', '-o', '{out}', '--dt', '-1'], 'dt must be a positive'),
    (['ingest', '{good}', '-o', '{out}', '--dt', '1', '--datum', '1'], '--datum'),
    (['ingest', '{good}', '-o', '{out}', '--dt', '1', '--gate-probability', '2'],
     'gate_probability'),
    (['import', '{bad}', '-o', '{outbag}'], 'line 3: lat'),
    (['bag-info', '{missing}'], 'no such bag'),
])
def test_bad_input_exits_2_with_one_line(tmp_path, gps_csv, capsys, argv, message):
    bad = tmp_path / 'bad.csv'
    bad.write_text('time,agent,lat,lon\n1,a,46,7\n2,a,?,7\n')
    paths = {'missing': tmp_path / 'missing.csv', 'bad': bad, 'good': gps_csv,
             'out': tmp_path / 'o.csv', 'outbag': tmp_path / 'ob'}
    rc = main([a.format(**{k: str(v) for k, v in paths.items()}) for a in argv])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2
    assert len(err) == 1 and err[0].startswith(f'herd-ros {argv[0]}: error:')
    assert message in err[0]


def test_large_herds_print_the_collars_that_lost_the_most():
    from herd_ros.ingest.pipeline import lost_most
    counters = {f'c{k}': {'accepted': 100, 'rejected_gate': k % 7, 'rejected_speed': k % 3,
                          'reinitialised': 50} for k in range(40)}
    shown = lost_most(counters, 3)
    lost = {a: c['rejected_gate'] + c['rejected_speed'] for a, c in counters.items()}
    assert len(shown) == 3
    assert sorted(lost[a] for a in shown) == sorted(lost.values())[-3:]
    assert list(shown) == [a for a in counters if a in shown]      # in the table's order


def test_the_track_clock_ticks_between_nearly_any_two_fixes(tmp_path, capsys):
    from herd_ros.errors import HerdInputError
    from herd_ros.ingest.pipeline import auto_dt, track_dt
    # intervals 40, 60, 300 (collar a) and 35, 35 (collar b); a 2 h silence is left out:
    # 10th percentile 35 s -> the largest round step not above it, 30 s
    fixes = pd.DataFrame({'agent': ['a'] * 5 + ['b'] * 3,
                          'time': [0.0, 40.0, 100.0, 400.0, 7600.0, 0.0, 35.0, 70.0]})
    assert track_dt(fixes) == 30.0
    # b now fixes every 9 s: 10th percentile 9 s -> 5 s; the herd clock of a model stays
    # the median interval, 40 s -> 30 s (the nearest round step on a log scale)
    fixes.loc[fixes['agent'] == 'b', 'time'] = [0.0, 9.0, 18.0]
    assert track_dt(fixes) == 5.0 and auto_dt(fixes) == 30.0
    # a 5 min duty cycle with bursts of 1 s fixes: at most ten ticks per median interval
    burst = pd.DataFrame({'agent': 'c', 'time': np.r_[np.arange(0.0, 30000.0, 300.0),
                                                       30000.0 + np.arange(60.0)]})
    assert track_dt(burst) == 30.0
    with pytest.raises(HerdInputError, match='--dt'):
        track_dt(pd.DataFrame({'agent': ['a'], 'time': [0.0]}))


def test_ingest_without_dt_writes_the_track_on_the_tracking_clock(gps_csv, tmp_path, capsys):
    # fixes every 1.0-1.3 s: the track ticks every second
    out = tmp_path / 'track.csv'
    assert main(['ingest', str(gps_csv), '-o', str(out)]) == 0
    assert 'ticks of 1 s (the 10th percentile of the fix intervals' in capsys.readouterr().out
    assert read_trajectory_csv(out)[0].dt == pytest.approx(1.0)
