"""rosbag2 written here reads back equal with rosbags and with the independent mcap readers."""
import numpy as np
import pandas as pd
import pytest
import yaml

from herd_ros.errors import HerdInputError
from herd_ros.io.bags import (BagWriter, bag_info, read_fix_bag, read_messages, typestore,
                              write_fix_bag)


def fixes():
    rng = np.random.default_rng(0)
    n = 40
    df = pd.DataFrame({
        'time': 1.7e9 + np.sort(rng.uniform(0, 60, n)).round(9),
        'agent': rng.choice(['cow_1', 'cow_2', 'x-3'], n),
        'lat': rng.uniform(-60, 60, n), 'lon': rng.uniform(-180, 180, n),
        'alt': np.where(rng.random(n) < 0.3, np.nan, rng.uniform(0, 2000, n)),
        'status': np.where(rng.random(n) < 0.1, -1, 0),
        'position_covariance_type': np.where(rng.random(n) < 0.5, 2, 0),
        'cov_ee': 4.0, 'cov_en': 0.0, 'cov_nn': 9.0})
    return df


def check_equal(back, df):
    back = back.sort_values(['time', 'agent']).reset_index(drop=True)
    df = df.sort_values(['time', 'agent']).reset_index(drop=True)
    assert list(back['agent']) == list(df['agent'])
    np.testing.assert_allclose(back['time'], df['time'], rtol=0, atol=1e-9 * 2e9 * 1e-9 + 1e-6)
    for col in ('lat', 'lon', 'alt'):
        np.testing.assert_array_equal(back[col], df[col])       # exact doubles, NaN kept
    np.testing.assert_array_equal(back['status'], df['status'])
    np.testing.assert_array_equal(back['position_covariance_type'],
                                  df['position_covariance_type'])


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_fix_bag_round_trip_with_rosbags(tmp_path, storage):
    df = fixes()
    bag = write_fix_bag(tmp_path / 'bag', df, storage=storage)
    meta = yaml.safe_load((bag / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert meta['version'] == 9 and meta['storage_identifier'] == storage
    check_equal(read_fix_bag(bag), df)
    info = bag_info(bag)
    assert info.storage == storage and info.message_count == len(df)
    assert info.topics['/herd/cow_1/fix'] == ('sensor_msgs/msg/NavSatFix',
                                              int((df['agent'] == 'cow_1').sum()))
    assert info.duration_s == pytest.approx(df['time'].max() - df['time'].min(), abs=1e-6)


def test_mcap_read_back_by_independent_readers(tmp_path):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    df = fixes()
    bag = write_fix_bag(tmp_path / 'bag', df)
    files = list(bag.glob('*.mcap'))
    assert len(files) == 1
    rows = []
    with open(files[0], 'rb') as fh:
        reader = make_reader(fh, decoder_factories=[DecoderFactory()])
        for schema, channel, message, msg in reader.iter_decoded_messages():
            assert schema.name == 'sensor_msgs/msg/NavSatFix'
            stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
            assert message.log_time == msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
            assert msg.header.frame_id == channel.topic.split('/')[2] + '_gps'
            cov = list(msg.position_covariance)
            if msg.position_covariance_type == 2:
                assert cov[0] == 4.0 and cov[4] == 9.0
            rows.append({'time': stamp, 'agent': channel.topic.split('/')[2],
                         'lat': msg.latitude, 'lon': msg.longitude, 'alt': msg.altitude,
                         'status': msg.status.status,
                         'position_covariance_type': msg.position_covariance_type})
    check_equal(pd.DataFrame(rows), df)
    # a bare .mcap file reads too
    check_equal(read_fix_bag(files[0]), df)


def test_generic_writer_and_reader_any_message(tmp_path):
    store = typestore()
    T = store.types
    with BagWriter(tmp_path / 'g') as bag:
        for k in range(5):
            pose = T['geometry_msgs/msg/Pose'](
                position=T['geometry_msgs/msg/Point'](x=float(k), y=2.0, z=0.0),
                orientation=T['geometry_msgs/msg/Quaternion'](x=0.0, y=0.0, z=0.0, w=1.0))
            header = T['std_msgs/msg/Header'](
                stamp=T['builtin_interfaces/msg/Time'](sec=100 + k, nanosec=0), frame_id='map')
            bag.write('/herd/poses', (100 + k) * 10**9,
                      T['geometry_msgs/msg/PoseArray'](header=header, poses=[pose, pose]))
            bag.write('/note', (100 + k) * 10**9 + 1, T['std_msgs/msg/String'](data=f'n{k}'))
    got = list(read_messages(tmp_path / 'g'))
    assert [g[0] for g in got] == ['/herd/poses', '/note'] * 5
    assert got[2][1] == 'geometry_msgs/msg/PoseArray' and got[2][2] == 101 * 10**9
    assert got[2][3].poses[1].position.x == 1.0 and got[3][3].data == 'n1'
    assert list(read_messages(tmp_path / 'g', topics=['/note']))[0][3].data == 'n0'
    info = bag_info(tmp_path / 'g')
    assert info.topics == {'/herd/poses': ('geometry_msgs/msg/PoseArray', 5),
                           '/note': ('std_msgs/msg/String', 5)}


def test_bag_errors(tmp_path):
    with pytest.raises(HerdInputError, match='no such bag'):
        read_fix_bag(tmp_path / 'nope')
    (tmp_path / 'empty').mkdir()
    with pytest.raises(HerdInputError, match='not a rosbag2 directory'):
        read_fix_bag(tmp_path / 'empty')
    T = typestore().types
    with BagWriter(tmp_path / 's') as bag:
        bag.write('/note', 1, T['std_msgs/msg/String'](data='x'))
    with pytest.raises(HerdInputError, match='no sensor_msgs/msg/NavSatFix topic'):
        read_fix_bag(tmp_path / 's')
    with pytest.raises(HerdInputError, match='already exists'):
        BagWriter(tmp_path / 's')


def test_a_fix_bag_with_a_broken_navsatfix_is_one_clear_error(tmp_path):
    """A message on a fix topic that is not a NavSatFix (cut short): one error naming the
    message, its topic and receive time, and how many there are."""
    from herd_ros.io.bags import NAVSATFIX, navsatfix
    store = typestore()
    good = store.serialize_cdr(navsatfix(store, 'a', 10.0, 48.1, 11.5, 500.0), NAVSATFIX)
    with BagWriter(tmp_path / 'b') as bag:
        bag.add_topic('/herd/a/fix', NAVSATFIX)
        bag.write_raw('/herd/a/fix', 10_000_000_000, good)
        bag.write_raw('/herd/a/fix', 11_000_000_000, good[:20])
    with pytest.raises(HerdInputError, match=r'message 2 on /herd/a/fix \(received at '
                                             r'11\.000 s\) is not a readable NavSatFix.*1 '
                                             r'such message'):
        read_fix_bag(tmp_path / 'b')
