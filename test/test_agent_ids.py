"""Agent ids made ROS name tokens where the data are read (herd_ros.agent_ids).

Independent expectations: rcl's rule for a name token (ASCII letters, digits, underscores,
not starting with a digit), checked by hand on each case; the same file read by every verb
gives the same ids, so a track written by `ingest` with collars named by serial number
fits, and `import` writes topics a ROS node can open.
"""
import re
import warnings

import numpy as np
import pandas as pd
import pytest

from herd_ros.agent_ids import AgentIdsRenamed, ros_agent_id, ros_agent_ids
from herd_ros.cli.main import main
from herd_ros.errors import HerdInputError
from herd_ros.ingest.geodesy import enu_to_geodetic
from herd_ros.trajectory import read_trajectory_csv

TOKEN = re.compile(r'^[A-Za-z][A-Za-z0-9_]*$')


@pytest.mark.parametrize('raw, expected', [
    ('cow_1', 'cow_1'),                  # already a token: kept as it is
    (' cow_1 ', 'cow_1'),                # stripped
    ('Cow 12', 'Cow_12'),                # a space
    ('4262-8483', 'id_4262_8483'),       # a serial number with a dash
    ('1_CPS4_45s', 'id_1_CPS4_45s'),     # starts with a digit
    ('_x', 'id__x'),                     # starts with an underscore
    ('vaca ñ', 'vaca__'),                # a letter outside ASCII
    (1234, 'id_1234'),                   # a number read as one
])
def test_ids_become_ros_name_tokens_by_hand(raw, expected):
    assert ros_agent_id(raw) == expected
    assert TOKEN.match(expected)


def test_renaming_is_said_once_and_two_ids_that_would_merge_are_refused():
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        assert ros_agent_ids(['cow_a', 'cow_b'], 'f.csv') == ['cow_a', 'cow_b']
    assert not caught                                    # nothing renamed: no note
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        assert ros_agent_ids(['Cow 12', '77'], 'f.csv') == ['Cow_12', 'id_77']
    (w,) = caught
    assert issubclass(w.category, AgentIdsRenamed)
    assert "'Cow 12' -> 'Cow_12'" in str(w.message) and "'77' -> 'id_77'" in str(w.message)
    with pytest.raises(HerdInputError, match="'Cow 12' and 'Cow_12' would both become"):
        ros_agent_ids(['Cow 12', 'Cow_12'], 'f.csv')


def test_collars_named_by_serial_number_ingest_fit_and_import(tmp_path, capsys):
    rng = np.random.default_rng(1)
    rows = []
    for name, (e0, n0) in (('4262-8483', (0.0, 0.0)), ('Cow 12', (30.0, 5.0)),
                           ('cow_c', (-20.0, 10.0))):
        t = 1.7e9 + 10.0 * np.arange(400) + rng.uniform(0, 1, 400)
        e = e0 + np.cumsum(rng.normal(0, 0.3, 400)) + rng.normal(0, 2, 400)
        n = n0 + np.cumsum(rng.normal(0, 0.3, 400)) + rng.normal(0, 2, 400)
        lat, lon, _ = enu_to_geodetic(e, n, 0.0, 27.0, -108.8, 100.0)
        rows.append(pd.DataFrame({'time': t, 'agent': name, 'lat': lat, 'lon': lon}))
    src = tmp_path / 'collars.csv'
    pd.concat(rows).sort_values('time').to_csv(src, index=False, float_format='%.9f')
    track = tmp_path / 'track.csv'
    assert main(['ingest', str(src), '-o', str(track)]) == 0
    err = capsys.readouterr().err
    assert "herd-ros ingest: note: " in err and "'4262-8483' -> 'id_4262_8483'" in err
    (run,) = read_trajectory_csv(track)
    assert sorted(run.agents) == ['Cow_12', 'cow_c', 'id_4262_8483']
    # the track fits (the ids are the model's parameter names) and predicts on itself
    model = tmp_path / 'model.yaml'
    assert main(['fit', str(track), '-o', str(model), '--terms', 'damping']) == 0
    assert 'id_4262_8483' in model.read_text()
    assert main(['predict', str(model), str(track), '-o', str(tmp_path / 'p.csv')]) == 0
    # a bag whose topics a ROS node can open (no token starts with a digit)
    from herd_ros.io.bags import bag_info
    bag = tmp_path / 'bag'
    assert main(['import', str(src), '-o', str(bag)]) == 0
    topics = sorted(bag_info(bag).topics)
    assert topics == ['/herd/Cow_12/fix', '/herd/cow_c/fix', '/herd/id_4262_8483/fix']


def test_a_frame_id_names_its_collar_as_the_readers_would():
    from herd_ros.ingest.fix_stream import collar_frames, frame_collar
    frames = collar_frames(['id_4262_8483', 'cow_c'])
    assert [frame_collar(frames, f) for f in ('4262-8483', '4262-8483_gps', '4262-8483/gps',
                                              'cow c', 'cow c/gps')] == [0, 0, 0, 1, 1]
    assert [frame_collar(frames, f) for f in ('cow x', '', '  ', '4262')] == [-1] * 4
