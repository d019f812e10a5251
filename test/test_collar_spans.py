"""No collar's data dropped (issue 25, acceptance 2).

Three collars with staggered spans — one starting late, one ending early, one outliving the
others by a day — go through ``herd-ros ingest`` with no options. The expectation is
independent of the filter: every collar's track must cover its own span (from its first fix
to its last, as the file says), whatever the others do.
"""
import numpy as np
import pandas as pd

from herd_ros.cli.main import main
from herd_ros.ingest.geodesy import enu_to_geodetic
from herd_ros.trajectory import read_trajectory_csv

DATUM = (45.0, 7.0, 300.0)


def staggered_fixes():
    """Fixes every 60 s of three slowly wandering animals: ``early`` over hours 0-10,
    ``late`` over hours 3-24, ``long`` over hours 0-48 (a day after the others end)."""
    rng = np.random.default_rng(4)
    spans = {'early': (0.0, 10.0), 'late': (3.0, 24.0), 'long': (0.0, 48.0)}
    rows = []
    for k, (agent, (h0, h1)) in enumerate(spans.items()):
        t = np.arange(h0 * 3600.0, h1 * 3600.0 + 1.0, 60.0)
        walk = np.cumsum(rng.normal(0.0, 1.0, (len(t), 2)), axis=0) + [100.0 * k, 0.0]
        lat, lon, alt = enu_to_geodetic(walk[:, 0], walk[:, 1], np.zeros(len(t)), *DATUM)
        rows.append(pd.DataFrame({'time': t, 'agent': agent, 'lat': lat, 'lon': lon,
                                  'alt': alt}))
    return pd.concat(rows).sort_values(['time', 'agent']), spans


def test_every_collar_keeps_its_own_span(tmp_path, capsys):
    fixes, spans = staggered_fixes()
    gps = tmp_path / 'gps.csv'
    fixes.to_csv(gps, index=False, float_format='%.10f')
    out = tmp_path / 'track.csv'
    assert main(['ingest', str(gps), '-o', str(out)]) == 0
    printed = capsys.readouterr().out
    track = read_trajectory_csv(out, require_uniform=False)[0]
    t0 = fixes['time'].min()
    for agent, (h0, h1) in spans.items():
        i = track.agents.index(agent)
        have = track.times[np.isfinite(track.positions[:, i, 0])] - t0
        assert have.min() <= h0 * 3600.0 + 120.0, agent
        assert have.max() >= h1 * 3600.0 - 120.0, agent
        n_fixes = int((fixes['agent'] == agent).sum())
        # a position at (almost) every tick of its span: the clock ticks once a minute
        assert len(have) >= 0.95 * n_fixes, agent
        assert agent in printed
    # the last day belongs to 'long' alone and is there
    i = track.agents.index('long')
    last_day = track.times - t0 > 25 * 3600.0
    assert np.isfinite(track.positions[last_day, i, 0]).mean() > 0.95
    assert 'union' in printed
