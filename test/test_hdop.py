"""Fixes whose error scales with their HDOP (ctmm's error model, σ = UERE · HDOP): read
from every format that carries it, σ_m fitted as the UERE where the data say so, and the
track filtered with each fix's own std.

Known truth: a random walk seen with a fix std of 3 m × HDOP (HDOP 0.8-8, drawn per fix)
or with one std of 5 m whatever the HDOP; the fit's choice and UERE are checked against
the generator's, the track against the true path, and the compiled bank against the
reference filter fix by fix.
"""
import numpy as np
import pandas as pd
import pytest

from herd_ros.ingest.geodesy import enu_to_geodetic
from herd_ros.ingest.motion_fit import fit_motion
from herd_ros.ingest.motion_refit import fix_variance
from herd_ros.ingest.pipeline import trajectory_from_fixes
from herd_ros.io.gps_files import read_fix_file

DATUM = (42.0, -72.0, 100.0)
UERE = 3.0


def walk(seed, n=400, diffusion=0.02, hdop_scaled=True):
    """(t, truth (n, 2), fixes (n, 2), hdop (n,)): a random walk of D per axis seen at
    30-300 s with fix std UERE × HDOP (or 5 m for every fix)."""
    rng = np.random.default_rng(seed)
    t = 1.6e9 + np.concatenate([[0.0], np.cumsum(rng.uniform(30.0, 300.0, n - 1))])
    steps = rng.normal(0.0, 1.0, (n, 2)) * np.sqrt(2 * diffusion * np.r_[0.0, np.diff(t)])[:, None]
    truth = np.cumsum(steps, axis=0)
    hdop = np.round(np.exp(rng.uniform(np.log(0.8), np.log(8.0), n)), 1)
    std = UERE * hdop if hdop_scaled else np.full(n, 5.0)
    return t, truth, truth + rng.normal(0.0, 1.0, (n, 2)) * std[:, None], hdop


def gps_table(t, z, hdop, agent='cow'):
    lat, lon, _ = enu_to_geodetic(z[:, 0], z[:, 1], 0.0, *DATUM)
    return pd.DataFrame({'time': t, 'agent': agent, 'lat': lat, 'lon': lon, 'hdop': hdop})


def test_every_format_that_carries_an_hdop_gives_it(tmp_path):
    (tmp_path / 'a.csv').write_text('time,agent,lat,lon,hdop\n1,a,42,-72,1.5\n2,a,42,-72,\n')
    (tmp_path / 'b.csv').write_text(
        'timestamp,location-long,location-lat,individual-local-identifier,gps:hdop\n'
        '2020-01-01 00:00:00.000,-72,42,a,2.5\n2020-01-01 00:01:00.000,-72,42,a,0.9\n')
    (tmp_path / 'c.gpx').write_text(
        '<?xml version="1.0"?><gpx version="1.1" xmlns="http://www.topografix.com/GPX/1/1">'
        '<trk><name>a</name><trkseg><trkpt lat="42" lon="-72"><time>2020-01-01T00:00:00Z'
        '</time><hdop>3.5</hdop></trkpt></trkseg></trk></gpx>')
    assert np.array_equal(read_fix_file(tmp_path / 'a.csv')['hdop'].to_numpy(),
                          [1.5, np.nan], equal_nan=True)
    assert read_fix_file(tmp_path / 'b.csv')['hdop'].tolist() == [2.5, 0.9]
    assert read_fix_file(tmp_path / 'c.gpx')['hdop'].tolist() == [3.5]
    (tmp_path / 'd.csv').write_text('time,agent,lat,lon,hdop\n1,a,42,-72,bad\n')
    with pytest.raises(Exception, match='line 2: hdop'):
        read_fix_file(tmp_path / 'd.csv')


def test_the_fit_takes_the_hdop_where_the_error_scales_with_it():
    """σ_m is the UERE (3 m) within 10 % where the fixes' error is 3 m × HDOP, and one
    σ_m (5 m within 10 %) where the error does not depend on the HDOP."""
    for seed in range(3):
        t, _, z, h = walk(seed)
        var = fix_variance(np.zeros(len(t)), np.full(len(t), np.nan), np.full(len(t), np.nan),
                           0.02, h)
        (fit,) = fit_motion([(t, z, var)], max_fixes=400, position_std_floor=0.02)
        assert fit.hdop and fit.position_std == pytest.approx(UERE, rel=0.1), fit
        t, _, z, h = walk(seed, hdop_scaled=False)
        var = fix_variance(np.zeros(len(t)), np.full(len(t), np.nan), np.full(len(t), np.nan),
                           0.02, h)
        (fit,) = fit_motion([(t, z, var)], max_fixes=400, position_std_floor=0.02)
        assert not fit.hdop and fit.position_std == pytest.approx(5.0, rel=0.1), fit


@pytest.mark.usefixtures('kernels')
def test_the_track_with_the_hdop_is_nearer_the_truth_and_the_bank_is_the_reference():
    """Three collars of the HDOP-scaled walk: the ingest with the HDOP column is nearer the
    true path at the fixes than the same fixes without it (RMS), and the compiled bank
    gives the reference filter's outcomes and positions."""
    tables, truths = [], {}
    for seed in range(3):
        t, truth, z, h = walk(10 + seed, n=600)
        tables.append(gps_table(t, z, h, f'cow_{seed}'))
        truths[f'cow_{seed}'] = (t, truth)
    fixes = pd.concat(tables).sort_values('time').reset_index(drop=True)

    def rms(traj):
        errors = []
        for i, a in enumerate(traj.agents):
            t, truth = truths[a]
            tl = traj.meta['timelines'][a]
            k = np.searchsorted(tl.t, t, side='right') - 1      # the state after each fix
            ok = k >= 0
            errors.append(np.hypot(*(tl.x[k[ok], :2] - truth[ok]).T))
        return float(np.sqrt(np.mean(np.concatenate(errors) ** 2)))

    with_hdop = trajectory_from_fixes(fixes, 60.0, datum=DATUM)
    without = trajectory_from_fixes(fixes.drop(columns='hdop'), 60.0, datum=DATUM)
    assert all(f.hdop for f in with_hdop.meta['motion_fits'].values())
    assert rms(with_hdop) < 0.9 * rms(without), (rms(with_hdop), rms(without))
    reference = trajectory_from_fixes(fixes, 60.0, datum=DATUM, engine='filterpy')
    assert list(reference.meta['fix_outcomes']) == list(with_hdop.meta['fix_outcomes'])
    for a in with_hdop.agents:
        assert np.allclose(reference.meta['timelines'][a].x, with_hdop.meta['timelines'][a].x,
                           atol=1e-6)
