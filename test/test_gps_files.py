"""Readers of GPS CSV, Movebank CSV and GPX into the fixes table; errors name file/line/field."""
import numpy as np
import pytest

from herd_ros.errors import HerdInputError
from herd_ros.io.gps_files import (read_fix_file, read_gps_csv, read_gpx, read_movebank_csv,
                                   sniff_format)

GPX = """<?xml version="1.0" encoding="UTF-8"?>
<gpx version="1.1" creator="test" xmlns="http://www.topografix.com/GPX/1/1">
  <trk><name>cow_7</name><trkseg>
    <trkpt lat="46.5" lon="7.25"><ele>1200.5</ele><time>2024-05-01T10:00:00Z</time></trkpt>
    <trkpt lat="46.50001" lon="7.25002"><time>2024-05-01T10:00:01.5Z</time></trkpt>
  </trkseg></trk>
  <trk><trkseg>
    <trkpt lat="-10" lon="20"><time>2024-05-01T12:00:00+02:00</time></trkpt>
  </trkseg></trk>
</gpx>
"""
T0 = 1714557600.0          # 2024-05-01T10:00:00Z


def test_gps_csv_epoch_and_iso(tmp_path):
    p = tmp_path / 'a.csv'
    p.write_text('time,agent,lat,lon,alt\n1714557600,cow_1,46.5,7.25,\n'
                 '1714557601.25,cow_1,46.5,7.25,1200\n')
    df = read_gps_csv(p)
    np.testing.assert_allclose(df['time'], [T0, T0 + 1.25])
    assert np.isnan(df['alt'][0]) and df['alt'][1] == 1200
    assert list(df['status']) == [0, 0] and list(df['position_covariance_type']) == [0, 0]
    q = tmp_path / 'b.csv'
    q.write_text('time,agent,lat,lon\n2024-05-01T10:00:00Z,c,46.5,7.25\n'
                 '2024-05-01T12:00:01+02:00,c,46.5,7.25\n2024-05-01 10:00:02,c,1,2\n')
    np.testing.assert_allclose(read_gps_csv(q)['time'], [T0, T0 + 1, T0 + 2])
    assert sniff_format(q) == 'gps'


def test_gps_csv_errors_name_line_and_field(tmp_path):
    p = tmp_path / 'bad.csv'
    p.write_text('time,agent,lat,lon\n1,a,46,7\n2,a,north,7\n')
    with pytest.raises(HerdInputError, match=r'bad.csv: line 3: lat is .north.'):
        read_gps_csv(p)
    p.write_text('time,agent,lat\n1,a,46\n')
    with pytest.raises(HerdInputError, match='missing column.*lon'):
        read_gps_csv(p)
    p.write_text('time,agent,lat,lon\n1,a,46,7\nyesterday,a,46,7\n')
    with pytest.raises(HerdInputError, match='line 3: time'):
        read_gps_csv(p)
    p.write_text('time,agent,lat,lon\n1,a,95,7\n')
    with pytest.raises(HerdInputError, match='line 2: lat .* outside'):
        read_gps_csv(p)
    with pytest.raises(HerdInputError, match='no such file'):
        read_gps_csv(tmp_path / 'missing.csv')


def test_movebank(tmp_path):
    p = tmp_path / 'mb.csv'
    p.write_text('event-id,timestamp,location-long,location-lat,individual-local-identifier,'
                 'height-above-ellipsoid\n'
                 '1,2024-05-01 10:00:00.000,7.25,46.5,Berta,1200\n'
                 '2,2024-05-01 10:05:00.000,,,Berta,\n'
                 '3,2024-05-01 10:00:30.000,7.26,46.4,Olga,\n')
    assert sniff_format(p) == 'movebank'
    df = read_fix_file(p)
    assert list(df['agent']) == ['Berta', 'Berta', 'Olga']
    np.testing.assert_allclose(df['time'], [T0, T0 + 300, T0 + 30])
    assert df['lat'][0] == 46.5 and df['lon'][0] == 7.25 and df['alt'][0] == 1200
    assert np.isnan(df['lat'][1])          # a missing location stays as a NaN fix
    p.write_text('timestamp,location-long,location-lat\n2024-05-01 10:00:00,1,2\n')
    with pytest.raises(HerdInputError, match='individual-local-identifier'):
        read_movebank_csv(p)


def test_gpx(tmp_path):
    p = tmp_path / 'walk.gpx'
    p.write_text(GPX)
    assert sniff_format(p) == 'gpx'
    df = read_gpx(p)
    assert list(df['agent']) == ['cow_7', 'cow_7', 'walk_2']
    np.testing.assert_allclose(df['time'], [T0, T0 + 1.5, T0])
    np.testing.assert_allclose(df['lat'], [46.5, 46.50001, -10])
    assert df['alt'][0] == 1200.5 and np.isnan(df['alt'][1])
    p.write_text(GPX.replace('lat="46.5"', 'lat="x"'))
    with pytest.raises(HerdInputError, match=r"walk.gpx: track 'cow_7' point 1: lat/lon"):
        read_gpx(p)
    p.write_text('<gpx><trk><trkseg>')
    with pytest.raises(HerdInputError, match='not valid XML'):
        read_gpx(p)


def test_normalise_keeps_a_fixes_table_and_converts_anything_else(tmp_path):
    import pandas as pd

    from herd_ros.io.gps_files import FIX_COLUMNS, normalise_fixes
    p = tmp_path / 'a.csv'
    p.write_text('time,agent,lat,lon\n1,7,46.5,7.25\n2,7,46.5,7.25\n')
    fixes = read_gps_csv(p)
    assert normalise_fixes(fixes) is fixes          # a reader's table: no copy
    raw = pd.DataFrame({'agent': [7, 8], 'time': [2, 1], 'lat': [46.5, 46.6],
                        'lon': [7.25, 7.3], 'status': [0.0, np.nan]}, index=[5, 3])
    out = normalise_fixes(raw)
    assert out is not raw and tuple(out.columns) == FIX_COLUMNS
    assert list(out['agent']) == ['7', '8'] and list(out['status']) == [0, 0]
    assert out['time'].dtype == np.float64 and list(out.index) == [0, 1]
    assert list(raw.columns) == ['agent', 'time', 'lat', 'lon', 'status']    # untouched
    shifted = fixes.iloc[1:]                        # not the default index: a new table
    assert list(normalise_fixes(shifted).index) == [0]
    # the reader made the id '7' a ROS name (herd_ros.agent_ids); normalise_fixes itself
    # only converts an id that is not a str
    ids = fixes.assign(agent=fixes['agent'].astype(object).where([True, False], 3))
    assert list(normalise_fixes(ids)['agent']) == ['id_7', '3']


def test_gps_columns_under_other_names_are_read_and_said(tmp_path):
    import warnings

    from herd_ros.errors import InputNote
    from herd_ros.io.gps_files import read_fix_file, sniff_format
    p = tmp_path / 'logger.csv'
    p.write_text('Timestamp,ID,Latitude,Longitude,alt\n'
                 '2015-08-06T17:15:20Z,007,27.0,-108.8,300\n'
                 '2015-08-06T17:15:50Z,007,27.0001,-108.8,301\n')
    assert sniff_format(p) == 'gps'
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        fixes = read_fix_file(p)
    notes = [str(w.message) for w in caught if issubclass(w.category, InputNote)]
    assert any("'Timestamp' read as 'time'" in n and "'ID' read as 'agent'" in n
               and "'Latitude' read as 'lat'" in n for n in notes), notes
    # the id kept as text (not the number 7), then made a ROS name
    assert list(fixes['agent']) == ['id_007', 'id_007']
    assert list(fixes['time']) == [1438881320.0, 1438881350.0]
    assert list(fixes['lat']) == [27.0, 27.0001] and list(fixes['alt']) == [300.0, 301.0]
    # a file that names its columns as the GPS CSV does is read without a note
    q = tmp_path / 'plain.csv'
    q.write_text('time,agent,lat,lon\n1,cow_a,27.0,-108.8\n')
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter('always')
        read_fix_file(q)
    assert not [w for w in caught if issubclass(w.category, InputNote)]


def test_two_columns_that_could_be_one_are_one_clear_error(tmp_path):
    from herd_ros.io.gps_files import read_gps_csv
    p = tmp_path / 'two.csv'
    p.write_text('time,id,animal,lat,lon\n1,a,b,27.0,-108.8\n')
    with pytest.raises(HerdInputError, match="'id', 'animal' could each be the 'agent' "
                                             "column"):
        read_gps_csv(p)
