"""The batched CDR codec of the live ingest against rclpy's own serializer (the reference):
every frame-id length (each gives another alignment), NaN and extreme values. Encoded
messages have the reference's length and deserialize, with rclpy, to the reference message
(the alignment padding is not compared: rclpy leaves whatever was in its buffer there)."""
import math

import numpy as np
import pytest
from geometry_msgs.msg import Pose, PoseArray
from nav_msgs.msg import Odometry
from rclpy.serialization import deserialize_message, serialize_message
from sensor_msgs.msg import NavSatFix

from herd_ros.io.cdr import (BATCH_DECODE_MIN, CdrError, OdometryEncoder, decode_navsatfix,
                             decode_navsatfixes, encode_pose_array, stamp_parts)

NAMES = ['', 'a', 'ab', 'abc', 'abcd', 'cow_1', 'cow_0001_gps', 'c' * 13, 'ünïcode_ß']


def _fix(frame, k):
    msg = NavSatFix()
    msg.header.frame_id = frame
    msg.header.stamp.sec = 1_700_000_000 + k
    msg.header.stamp.nanosec = 123_456_789 * k % 1_000_000_000
    msg.status.status = [-1, 0, 1, 2][k % 4]
    msg.status.service = 1 + k % 8
    msg.latitude = 46.8 + 1e-7 * k
    msg.longitude = -108.79 - 3e-7 * k
    msg.altitude = [math.nan, 550.25, -12.0][k % 3]
    msg.position_covariance = [float(v) * (k + 1) for v in range(9)]
    msg.position_covariance_type = k % 4
    return msg


def test_navsatfix_decodes_as_rclpy_serialized_it():
    msgs = [_fix(name, k) for k, name in enumerate(NAMES)]
    batch, bad = decode_navsatfixes([serialize_message(m) for m in msgs])
    assert bad == []
    for k, msg in enumerate(msgs):
        assert batch.frame_id[k] == msg.header.frame_id
        assert batch.stamp[k] == msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
        assert batch.status[k] == msg.status.status
        assert batch.lat[k] == msg.latitude and batch.lon[k] == msg.longitude
        assert (batch.alt[k] == msg.altitude
                or (math.isnan(batch.alt[k]) and math.isnan(msg.altitude)))
        assert batch.cov[k].tolist() == list(msg.position_covariance)
        assert batch.cov_type[k] == msg.position_covariance_type


def test_a_large_batch_is_read_at_once_as_message_by_message():
    """Batches of BATCH_DECODE_MIN messages and more are read at once: every frame-id length
    and field as rclpy serialized it, the same as each message alone; one big-endian or
    malformed message in the batch sends the whole batch message by message."""
    msgs = [_fix(NAMES[k % len(NAMES)] + str(k % 7) * (k % 3), k)
            for k in range(3 * BATCH_DECODE_MIN)]
    data = [serialize_message(m) for m in msgs]
    batch, bad = decode_navsatfixes(data)
    assert bad == []
    for k, msg in enumerate(msgs):
        row = decode_navsatfix(data[k])
        assert batch.frame_id[k] == row[0] == msg.header.frame_id
        assert batch.stamp[k] == row[1] + 1e-9 * row[2]
        assert batch.status[k] == row[3] == msg.status.status
        assert (batch.lat[k], batch.lon[k]) == (row[4], row[5]) == (msg.latitude, msg.longitude)
        assert batch.alt[k] == row[6] or (math.isnan(batch.alt[k]) and math.isnan(row[6]))
        assert tuple(batch.cov[k]) == row[7] == tuple(msg.position_covariance)
        assert batch.cov_type[k] == row[8] == msg.position_covariance_type
    mixed, bad = decode_navsatfixes(data[:100] + [b'\x00\x01\x00\x00' + bytes(5)] + data[100:])
    assert [k for k, _ in bad] == [100] and mixed.frame_id == batch.frame_id
    assert np.array_equal(mixed.cov, batch.cov) and np.array_equal(mixed.stamp, batch.stamp)


def test_big_endian_navsatfix():
    """A big-endian sender (allowed by CDR) is read too: swap every field by hand."""
    msg = _fix('cow_7', 3)
    le = serialize_message(msg)
    import struct
    be = bytearray(b'\x00\x00\x00\x00') + bytearray(le[4:])
    struct.pack_into('>iII', be, 4, msg.header.stamp.sec, msg.header.stamp.nanosec, 6)
    body = 12 + 6 + 1                       # status int8, then uint16 service at 20
    struct.pack_into('>H', be, 4 + body + 1, msg.status.service)
    start = 4 + 24
    values = [msg.latitude, msg.longitude, msg.altitude] + list(msg.position_covariance)
    struct.pack_into('>12d', be, start, *values)
    row = decode_navsatfix(bytes(be))
    assert row[0] == 'cow_7' and row[1:3] == (msg.header.stamp.sec, msg.header.stamp.nanosec)
    assert row[4] == msg.latitude and row[7] == tuple(msg.position_covariance)


@pytest.mark.parametrize('data, why', [
    (b'', 'encapsulation'),
    (b'\x07\x07\x00\x00' + bytes(60), 'encapsulation'),
    (b'\x00\x01\x00\x00' + bytes(8) + b'\xff\xff\x00\x00', 'frame_id'),
    (None, 'short'),
])
def test_malformed_fixes_are_named_and_the_rest_kept(data, why):
    good = serialize_message(_fix('cow_1', 1))
    if data is None:
        data = good[:-20]                   # cut short
    with pytest.raises(CdrError, match=why if why != 'short' else 'too short'):
        decode_navsatfix(data)
    batch, bad = decode_navsatfixes([good, data, good])
    assert len(batch.stamp) == 2 and [k for k, _ in bad] == [1]


def test_odometry_encodes_as_rclpy():
    rng = np.random.default_rng(4)
    names = NAMES[1:]
    enc = OdometryEncoder(names, 'map', 1e6)
    m = 40
    collar = rng.integers(0, len(names), m)
    stamp = 1.7e9 + rng.uniform(0, 1e5, m)
    stamp[0] = 0.0
    stamp[1] = 1.7e9 + 0.9999999996          # rounds up to the next second
    x = rng.normal(0, 500, (m, 4))
    A = rng.normal(0, 1, (m, 4, 4))
    P = A @ np.swapaxes(A, 1, 2)
    out = enc.encode(collar, stamp, x, P)
    for k in range(m):
        ref = Odometry()
        ref.header.frame_id = 'map'
        ref.child_frame_id = names[collar[k]]
        ns = int(round(stamp[k] * 1e9))
        ref.header.stamp.sec, ref.header.stamp.nanosec = ns // 10**9, ns % 10**9
        ref.pose.pose.position.x, ref.pose.pose.position.y = float(x[k, 0]), float(x[k, 1])
        ref.pose.pose.orientation.w = 1.0
        ref.twist.twist.linear.x, ref.twist.twist.linear.y = float(x[k, 2]), float(x[k, 3])
        c = np.diag(np.full(6, 1e6))
        c[:2, :2] = P[k, :2, :2]
        ref.pose.covariance = c.reshape(36)
        c = np.diag(np.full(6, 1e6))
        c[:2, :2] = P[k, 2:, 2:]
        ref.twist.covariance = c.reshape(36)
        assert len(out[k]) == len(serialize_message(ref)), k
        assert deserialize_message(out[k], Odometry) == ref, k
    back = deserialize_message(out[1], Odometry)
    assert (back.header.stamp.sec, back.header.stamp.nanosec) == (1_700_000_001, 0)


def test_pose_array_encodes_as_rclpy_with_missing_collars():
    pos = np.array([[1.5, -2.0], [np.nan, np.nan], [1e6, 3.25]])
    for frame in ('map', 'odom_x', 'a'):
        ref = PoseArray()
        ref.header.frame_id = frame
        ref.header.stamp.sec, ref.header.stamp.nanosec = 1_700_000_010, 500_000_000
        for (px, py) in pos.tolist():
            pose = Pose()
            pose.position.x, pose.position.y = px, py
            pose.position.z = 0.0 if math.isfinite(px) else math.nan
            pose.orientation.w = 1.0
            ref.poses.append(pose)
        data = encode_pose_array(1_700_000_010.5, frame, pos)
        assert len(data) == len(serialize_message(ref))
        back = deserialize_message(data, PoseArray)
        assert back.header == ref.header and len(back.poses) == 3
        for got, want in zip(back.poses, ref.poses):
            a = [got.position.x, got.position.y, got.position.z, got.orientation.x,
                 got.orientation.y, got.orientation.z, got.orientation.w]
            b = [want.position.x, want.position.y, want.position.z, want.orientation.x,
                 want.orientation.y, want.orientation.z, want.orientation.w]
            np.testing.assert_array_equal(a, b)
    empty = deserialize_message(encode_pose_array(5.0, 'map', np.zeros((0, 2))), PoseArray)
    assert empty.poses == [] and empty.header.stamp.sec == 5


def test_stamp_parts_rounds_like_seconds_to_stamp():
    from herd_ros.nodes.ros_common import seconds_to_stamp
    ts = np.array([0.0, -3.0, 1.5, 1_700_000_000.123456789, 2.9999999999])
    sec, nanosec = stamp_parts(ts)
    for t, s, n in zip(ts, sec, nanosec):
        ref = seconds_to_stamp(float(t))
        assert (s, n) == (ref.sec, ref.nanosec)
