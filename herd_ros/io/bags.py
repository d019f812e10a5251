"""rosbag2 reading and writing with ``rosbags`` (Jazzy typestore), no ROS install needed.

* :func:`write_fix_bag` / :func:`read_fix_bag`: a fixes table (see
  :mod:`herd_ros.io.gps_files`) <-> ``sensor_msgs/msg/NavSatFix`` on ``/herd/<agent>/fix``,
  header stamp = fix time = bag receive time, ``frame_id = <agent>_gps``.
* :class:`BagWriter`: any messages to a new bag (mcap by default, metadata version 9).
* :func:`read_messages`: ``(topic, msgtype, timestamp_ns, message)`` for every message of
  any topic, in time order, from an mcap or sqlite3 bag directory or a bare ``.mcap`` file
  (types the bag embeds are registered, so non-Jazzy types deserialize too).
* :func:`bag_info`: duration, storage, topics with types and counts.

Errors (missing bag, unreadable storage, no NavSatFix topic) raise
:class:`herd_ros.errors.HerdInputError` naming the bag.
"""
from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from herd_ros.errors import HerdInputError

NAVSATFIX = 'sensor_msgs/msg/NavSatFix'
FIX_TOPIC_RE = re.compile(r'^/herd/(?P<agent>[^/]+)/fix$')


def typestore():
    """The ROS 2 Jazzy typestore of ``rosbags``."""
    from rosbags.typesys import Stores, get_typestore
    return get_typestore(Stores.ROS2_JAZZY)


def fix_topic(agent: str) -> str:
    """``/herd/<agent>/fix`` (DESIGN.md, topics)."""
    return f'/herd/{agent}/fix'


def _split_ns(t_ns: int) -> tuple[int, int]:
    return int(t_ns // 1_000_000_000), int(t_ns % 1_000_000_000)


def seconds_to_ns(t: float) -> int:
    """Epoch seconds -> integer nanoseconds (rounded to the nearest ns)."""
    return int(round(float(t) * 1e9))


class BagWriter:
    """Write any messages to a rosbag2 (context manager).

    Example::

        with BagWriter('out_bag') as bag:
            bag.write('/herd/cow_1/fix', t_ns, msg)      # msg from typestore().types[...]

    Args:
        path: the bag directory to create (must not exist).
        storage: ``'mcap'`` (default) or ``'sqlite3'``.
        version: rosbag2 metadata version (9 = Jazzy).
    """

    def __init__(self, path, storage: str = 'mcap', version: int = 9):
        from rosbags.rosbag2 import StoragePlugin, Writer
        plugins = {'mcap': StoragePlugin.MCAP, 'sqlite3': StoragePlugin.SQLITE3}
        if storage not in plugins:
            raise HerdInputError(f'{path}: storage must be mcap or sqlite3, got {storage!r}')
        self.path = Path(path)
        if self.path.exists():
            raise HerdInputError(f'{self.path}: already exists; rosbag2 writes a new '
                                 f'directory')
        self.typestore = typestore()
        self._writer = Writer(self.path, version=version, storage_plugin=plugins[storage])
        self._connections = {}

    def open(self) -> 'BagWriter':
        self._writer.open()
        return self

    def __enter__(self) -> 'BagWriter':
        return self.open()

    def __exit__(self, *exc):
        self.close()

    def close(self) -> None:
        self._writer.close()

    def add_topic(self, topic: str, msgtype: str, offered_qos_profiles=()):
        """Declare a topic (done implicitly by :meth:`write`)."""
        if topic not in self._connections:
            if msgtype not in self.typestore.types:
                raise HerdInputError(f'{self.path}: message type {msgtype!r} is not in the '
                                     f'Jazzy typestore')
            self._connections[topic] = self._writer.add_connection(
                topic, msgtype, typestore=self.typestore,
                offered_qos_profiles=offered_qos_profiles)
        return self._connections[topic]

    def write(self, topic: str, timestamp_ns: int, msg, msgtype: str | None = None) -> None:
        """Serialize ``msg`` (CDR) and write it at receive time ``timestamp_ns``."""
        msgtype = msgtype or msg.__msgtype__
        conn = self.add_topic(topic, msgtype)
        self._writer.write(conn, int(timestamp_ns),
                           self.typestore.serialize_cdr(msg, msgtype))


def navsatfix(store, agent: str, t: float, lat: float, lon: float, alt: float = np.nan, *,
              status: int = 0, service: int = 1, covariance=None, covariance_type: int = 0,
              frame_id: str | None = None):
    """A ``sensor_msgs/msg/NavSatFix`` with header stamp ``t`` (epoch s)."""
    types = store.types
    sec, nsec = _split_ns(seconds_to_ns(t))
    header = types['std_msgs/msg/Header'](
        stamp=types['builtin_interfaces/msg/Time'](sec=sec, nanosec=nsec),
        frame_id=frame_id if frame_id is not None else f'{agent}_gps')
    cov = np.zeros(9) if covariance is None else np.asarray(covariance, dtype=np.float64)
    return types[NAVSATFIX](
        header=header,
        status=types['sensor_msgs/msg/NavSatStatus'](status=int(status), service=int(service)),
        latitude=float(lat), longitude=float(lon), altitude=float(alt),
        position_covariance=cov.astype(np.float64).reshape(9),
        position_covariance_type=int(covariance_type))


def _fix_covariance(row) -> tuple[np.ndarray, int]:
    cov_type = int(row.get('position_covariance_type', 0) or 0)
    cov = np.zeros(9)
    ee, en, nn = (row.get(k, np.nan) for k in ('cov_ee', 'cov_en', 'cov_nn'))
    if cov_type and np.isfinite([ee, en, nn]).all():
        cov[0], cov[1], cov[3], cov[4] = ee, en, en, nn
    else:
        cov_type = 0 if not np.isfinite([ee, nn]).all() else cov_type
    return cov, cov_type


def write_fix_bag(path, fixes, storage: str = 'mcap', progress: bool = False) -> Path:
    """Write a fixes table (columns ``time, agent, lat, lon`` and optionally ``alt, status,
    position_covariance_type, cov_ee, cov_en, cov_nn``) as NavSatFix on
    ``/herd/<agent>/fix``, in time order, receive time = header stamp."""
    fixes = fixes.sort_values('time', kind='stable')
    with BagWriter(path, storage=storage) as bag:
        store = bag.typestore
        rows = fixes.to_dict('records')
        if progress:
            from tqdm import tqdm
            rows = tqdm(rows, desc='writing bag', unit='fix')
        for row in rows:
            agent = str(row['agent'])
            cov, cov_type = _fix_covariance(row)
            status = row.get('status', 0)
            status = 0 if status is None or not np.isfinite(status) else int(status)
            alt = row.get('alt', np.nan)
            msg = navsatfix(store, agent, row['time'], row['lat'], row['lon'],
                            np.nan if alt is None else alt, status=status,
                            covariance=cov, covariance_type=cov_type)
            bag.write(fix_topic(agent), seconds_to_ns(row['time']), msg, NAVSATFIX)
    return Path(path)


def _open_reader(path):
    from rosbags.highlevel import AnyReader
    path = Path(path)
    if not path.exists():
        raise HerdInputError(f'{path}: no such bag')
    if path.is_dir() and not (path / 'metadata.yaml').exists():
        raise HerdInputError(f'{path}: not a rosbag2 directory (no metadata.yaml)')
    try:
        reader = AnyReader([path], default_typestore=typestore())
        reader.open()
    except HerdInputError:
        raise
    except Exception as exc:  # rosbags raises several reader errors
        raise HerdInputError(f'{path}: not a readable rosbag2 ({exc.__class__.__name__}: '
                             f'{exc})'.splitlines()[0]) from None
    return reader


def read_messages(path, topics=None):
    """Yield ``(topic, msgtype, timestamp_ns, message)`` for every message (of ``topics``
    if given) in receive-time order."""
    reader = _open_reader(path)
    try:
        conns = [c for c in reader.connections if topics is None or c.topic in topics]
        for conn, t_ns, raw in reader.messages(connections=conns):
            yield conn.topic, conn.msgtype, t_ns, reader.deserialize(raw, conn.msgtype)
    finally:
        reader.close()


def read_fix_bag(path, agents=None):
    """NavSatFix messages on ``/herd/<agent>/fix`` as a fixes table (pandas DataFrame:
    time from the header stamp, agent, lat, lon, alt, status, position_covariance_type,
    cov_ee, cov_en, cov_nn, receive_time)."""
    import pandas as pd
    reader = _open_reader(path)
    try:
        conns = []
        for c in reader.connections:
            m = FIX_TOPIC_RE.match(c.topic)
            if m and c.msgtype == NAVSATFIX and (agents is None or m['agent'] in agents):
                conns.append(c)
        if not conns:
            raise HerdInputError(f'{path}: no {NAVSATFIX} topic /herd/<agent>/fix in the bag '
                                 f'(topics: {", ".join(sorted({c.topic for c in reader.connections})) or "none"})')
        rows = {k: [] for k in ('time', 'agent', 'lat', 'lon', 'alt', 'status',
                                'position_covariance_type', 'cov_ee', 'cov_en', 'cov_nn',
                                'receive_time')}
        for conn, t_ns, raw in reader.messages(connections=conns):
            msg = reader.deserialize(raw, conn.msgtype)
            cov = np.asarray(msg.position_covariance, dtype=float)
            rows['time'].append(msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9)
            rows['agent'].append(FIX_TOPIC_RE.match(conn.topic)['agent'])
            rows['lat'].append(msg.latitude)
            rows['lon'].append(msg.longitude)
            rows['alt'].append(msg.altitude)
            rows['status'].append(int(msg.status.status))
            rows['position_covariance_type'].append(int(msg.position_covariance_type))
            rows['cov_ee'].append(cov[0])
            rows['cov_en'].append(cov[1])
            rows['cov_nn'].append(cov[4])
            rows['receive_time'].append(t_ns * 1e-9)
    finally:
        reader.close()
    return pd.DataFrame(rows)


@dataclass
class BagInfo:
    """Summary of a bag: ``topics`` maps topic -> (msgtype, message count)."""

    path: Path
    storage: str
    duration_s: float
    start_s: float
    end_s: float
    message_count: int
    topics: dict[str, tuple[str, int]]

    def __str__(self):
        lines = [f'bag:      {self.path}', f'storage:  {self.storage}',
                 f'duration: {self.duration_s:.3f} s ({self.start_s:.3f} .. {self.end_s:.3f})',
                 f'messages: {self.message_count}', 'topics:']
        width = max((len(t) for t in self.topics), default=0)
        for topic, (msgtype, count) in sorted(self.topics.items()):
            lines.append(f'  {topic:<{width}}  {count:>8}  {msgtype}')
        return '\n'.join(lines)


def bag_info(path) -> BagInfo:
    """Duration, topics (type, count), message count and storage of a bag."""
    from rosbags.rosbag2 import Reader
    path = Path(path)
    if not path.exists():
        raise HerdInputError(f'{path}: no such bag')
    try:
        with Reader(path) as reader:
            topics = {c.topic: (c.msgtype, c.msgcount) for c in reader.connections}
            storage = 'mcap' if path.suffix == '.mcap' else _storage_from_metadata(path)
            n = reader.message_count
            start, end = (reader.start_time, reader.end_time) if n else (0, 0)
    except HerdInputError:
        raise
    except Exception as exc:
        raise HerdInputError(f'{path}: not a readable rosbag2 ({exc.__class__.__name__}: '
                             f'{exc})'.splitlines()[0]) from None
    return BagInfo(path, storage, (end - start) * 1e-9, start * 1e-9, end * 1e-9, n, topics)


def _storage_from_metadata(path: Path) -> str:
    meta = path / 'metadata.yaml'
    if meta.exists():
        m = re.search(r'storage_identifier:\s*(\S+)', meta.read_text())
        if m:
            return m.group(1)
    return 'unknown'
