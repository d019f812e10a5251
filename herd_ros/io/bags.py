"""rosbag2 reading and writing with ``rosbags`` (Jazzy typestore), no ROS install needed.

* :func:`write_fix_bag` / :func:`read_fix_bag`: a fixes table (see
  :mod:`herd_ros.io.gps_files`) <-> ``sensor_msgs/msg/NavSatFix`` on ``/herd/<agent>/fix``,
  header stamp = fix time = bag receive time, ``frame_id = <agent>_gps``.
* :class:`BagWriter`: any messages to a new bag (mcap by default, metadata version 9);
  with ``crash_safe=True`` (mcap) the bag on disk stays readable while it is being written
  (what the ``record`` node relies on to survive ``kill -9``), see :meth:`BagWriter.flush`.
* :func:`read_messages`: ``(topic, msgtype, timestamp_ns, message)`` for every message of
  any topic, in time order, from an mcap or sqlite3 bag directory or a bare ``.mcap`` file
  (types the bag embeds are registered, so non-Jazzy types deserialize too).
* :func:`read_raw_messages`: the same without deserializing (CDR bytes), from a start time.
* :func:`bag_info`: duration, storage, topics with types, counts and offered QoS profiles.

Errors (missing bag, unreadable storage, no NavSatFix topic) raise
:class:`herd_ros.errors.HerdInputError` naming the bag.
"""
from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
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
    """``/herd/<agent>/fix`` (doc/formats.md, topics)."""
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
        crash_safe: mcap only. Bytes reach the file only in :meth:`flush` (and
            :meth:`close`), each time as one ``pwrite`` of the finished chunk followed by a
            closing Data End + Footer + magic, which the next flush overwrites; and
            ``metadata.yaml`` exists from :meth:`open` on and is rewritten (atomically) at
            every flush. A process killed between flushes therefore leaves a valid,
            unsummarised mcap (readers scan it: rosbags, the ``mcap`` library) holding every
            message up to the last flush. :meth:`close` writes the usual indexed summary.
    """

    def __init__(self, path, storage: str = 'mcap', version: int = 9,
                 crash_safe: bool = False):
        from rosbags.rosbag2 import StoragePlugin, Writer
        plugins = {'mcap': StoragePlugin.MCAP, 'sqlite3': StoragePlugin.SQLITE3}
        if storage not in plugins:
            raise HerdInputError(f'{path}: storage must be mcap or sqlite3, got {storage!r}')
        if crash_safe and storage != 'mcap':
            raise HerdInputError(f'{path}: crash-safe writing needs storage mcap, got '
                                 f'{storage!r}')
        self.path = Path(path)
        if self.path.exists():
            raise HerdInputError(f'{self.path}: already exists; rosbag2 writes a new '
                                 f'directory')
        self.typestore = typestore()
        self.crash_safe = crash_safe
        self._writer = Writer(self.path, version=version, storage_plugin=plugins[storage])
        self._connections = {}

    def open(self) -> 'BagWriter':
        """Open the bag for writing (crash-safe: the file committed as it is written);
        returns self."""
        self._writer.open()
        if self.crash_safe:
            storage = self._writer.storage
            storage.bio.close()                 # header already written through
            storage.bio = _CommitFile(storage.path)
            self.flush()
        return self

    def __enter__(self) -> 'BagWriter':
        return self.open()

    def __exit__(self, *exc):
        self.close()

    def close(self) -> None:
        """Close the bag (writes its metadata)."""
        self._writer.close()

    @property
    def message_count(self) -> int:
        """Messages written so far."""
        return sum(self._writer.counts.values())

    def add_topic(self, topic: str, msgtype: str, offered_qos_profiles=()):
        """Declare a topic (done implicitly by :meth:`write`). ``offered_qos_profiles``: a
        list of ``rosbags.interfaces.Qos``, stored in metadata.yaml and the mcap channel."""
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

    def write_raw(self, topic: str, timestamp_ns: int, data: bytes) -> None:
        """Write an already serialized (CDR) message on a topic declared with
        :meth:`add_topic`, at receive time ``timestamp_ns``."""
        if topic not in self._connections:
            raise HerdInputError(f'{self.path}: topic {topic!r} was not added before '
                                 f'writing raw data')
        self._writer.write(self._connections[topic], int(timestamp_ns), data)

    def flush(self) -> None:
        """Crash-safe mode: make everything written so far durable against a process kill
        (see the class docstring). A no-op otherwise."""
        if not self.crash_safe:
            return
        storage = self._writer.storage
        if storage.chunk.bio.tell():
            storage.close_chunk()
        storage.bio.commit(_MCAP_OPEN_END)
        _write_metadata_yaml(self._writer)


# Data End (op 0x0F, crc 0) + Footer (op 0x02: no summary) + magic: the end of an
# unsummarised mcap (https://mcap.dev/spec#footer-op0x02).
_MCAP_OPEN_END = (b'\x0f' + (4).to_bytes(8, 'little') + bytes(4)
                  + b'\x02' + (20).to_bytes(8, 'little') + bytes(20)
                  + b'\x89MCAP0\r\n')


class _CommitFile:
    """The binary file rosbags' mcap storage writes to, in crash-safe mode: writes are
    kept in memory until :meth:`commit`, which puts them plus a trailer on disk with one
    ``pwrite`` at the end of the committed data (the trailer is overwritten next time)."""

    def __init__(self, path: Path):
        self._fd = os.open(path, os.O_WRONLY)
        self._committed = os.fstat(self._fd).st_size
        self._pending = bytearray()

    def write(self, data) -> int:
        self._pending += data
        return len(data)

    def tell(self) -> int:
        return self._committed + len(self._pending)

    def flush(self) -> None:
        """Nothing: data reach the file in :meth:`commit` only."""

    def commit(self, trailer: bytes = b'') -> None:
        data = memoryview(bytes(self._pending) + trailer)
        offset = self._committed
        while data:
            n = os.pwrite(self._fd, data, offset)
            data, offset = data[n:], offset + n
        self._committed += len(self._pending)
        self._pending.clear()

    def close(self) -> None:
        self.commit()
        os.ftruncate(self._fd, self._committed)
        os.close(self._fd)


def _write_metadata_yaml(writer) -> None:
    """metadata.yaml of a rosbags ``Writer`` that is still open (the same content its
    ``close`` writes), replaced atomically."""
    from io import StringIO

    from rosbags.rosbag2.metadata import dump_qos_v8, dump_qos_v9
    from ruamel.yaml import YAML
    dump_qos = dump_qos_v9 if writer.version >= 9 else dump_qos_v8
    count = sum(writer.counts.values())
    start = writer.min_timestamp if count else 0
    duration = max(0, writer.max_timestamp - writer.min_timestamp) if count else 0
    name = writer.storage.path.name
    info = {
        'version': writer.version,
        'storage_identifier': writer.storage_plugin.name.lower(),
        'relative_file_paths': [name],
        'duration': {'nanoseconds': duration},
        'starting_time': {'nanoseconds_since_epoch': start},
        'message_count': count,
        'topics_with_message_count': [
            {'topic_metadata': {
                'name': c.topic, 'type': c.msgtype,
                'serialization_format': c.ext.serialization_format,
                'offered_qos_profiles': dump_qos(c.ext.offered_qos_profiles),
                'type_description_hash': c.digest},
             'message_count': writer.counts[c.id]}
            for c in writer.connections],
        'compression_format': '',
        'compression_mode': '',
        'files': [{'path': name, 'starting_time': {'nanoseconds_since_epoch': start},
                   'duration': {'nanoseconds': duration}, 'message_count': count}],
        'custom_data': writer.custom_data or None,
        'ros_distro': 'rosbags',
    }
    yaml = YAML(typ='safe')
    yaml.default_flow_style = False
    text = StringIO()
    yaml.dump({'rosbag2_bagfile_information': info}, text)
    tmp = writer.metapath.with_suffix('.yaml.tmp')
    tmp.write_text(text.getvalue(), 'utf8')
    tmp.replace(writer.metapath)


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


def read_raw_messages(path, topics=None, start_ns: int | None = None):
    """Yield ``(topic, msgtype, timestamp_ns, cdr_bytes)`` for every message (of ``topics``
    if given, received at or after ``start_ns`` if given) in receive-time order, without
    deserializing (what a player republishes as is)."""
    reader = _open_reader(path)
    try:
        conns = [c for c in reader.connections if topics is None or c.topic in topics]
        if conns:
            for conn, t_ns, raw in reader.messages(connections=conns, start=start_ns):
                yield conn.topic, conn.msgtype, t_ns, bytes(raw)
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
            topics = ', '.join(sorted({c.topic for c in reader.connections})) or 'none'
            raise HerdInputError(f'{path}: no {NAVSATFIX} topic /herd/<agent>/fix in the bag '
                                 f'(topics: {topics})')
        agent_of = {c.id: FIX_TOPIC_RE.match(c.topic)['agent'] for c in conns}
        topic_of = {c.id: c.topic for c in conns}
        ids, stamps_ns, raws = [], [], []
        for conn, t_ns, raw in reader.messages(connections=conns):
            ids.append(conn.id)
            stamps_ns.append(t_ns)
            raws.append(bytes(raw))
    finally:
        reader.close()
    # every message at once (herd_ros.io.cdr, the node's decoder: the same numbers as
    # rosbags' deserializer, ~20 × faster than it message by message)
    from herd_ros.io.cdr import decode_navsatfixes
    fixes, bad = decode_navsatfixes(raws)
    if bad:
        k, reason = bad[0]
        raise HerdInputError(f'{path}: message {k + 1} on {topic_of[ids[k]]} (received at '
                             f'{stamps_ns[k] * 1e-9:.3f} s) is not a readable NavSatFix '
                             f'({reason}); {len(bad)} such message(s) in all')
    return pd.DataFrame({
        'time': fixes.stamp, 'agent': [agent_of[i] for i in ids], 'lat': fixes.lat,
        'lon': fixes.lon, 'alt': fixes.alt, 'status': fixes.status,
        'position_covariance_type': fixes.cov_type, 'cov_ee': fixes.cov[:, 0],
        'cov_en': fixes.cov[:, 1], 'cov_nn': fixes.cov[:, 4],
        'receive_time': np.asarray(stamps_ns, dtype=np.int64) * 1e-9})


@dataclass
class BagInfo:
    """Summary of a bag: ``topics`` maps topic -> (msgtype, message count);
    ``offered_qos`` maps topic -> the QoS profiles its publishers offered when it was
    recorded (a list of ``rosbags.interfaces.Qos``; empty when the bag holds none);
    ``start_ns``/``end_ns``: first and last receive time (integer ns)."""

    path: Path
    storage: str
    duration_s: float
    start_s: float
    end_s: float
    message_count: int
    topics: dict[str, tuple[str, int]]
    start_ns: int = 0
    end_ns: int = 0
    offered_qos: dict[str, list] = field(default_factory=dict)

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
            qos = {c.topic: list(getattr(c.ext, 'offered_qos_profiles', None) or [])
                   for c in reader.connections}
            storage = 'mcap' if path.suffix == '.mcap' else _storage_from_metadata(path)
            n = reader.message_count
            start, end = (reader.start_time, reader.end_time) if n else (0, 0)
    except HerdInputError:
        raise
    except Exception as exc:
        raise HerdInputError(f'{path}: not a readable rosbag2 ({exc.__class__.__name__}: '
                             f'{exc})'.splitlines()[0]) from None
    # rosbags reports end_time as the last receive time + 1 ns
    last = end - 1 if n else 0
    return BagInfo(path, storage, (end - start) * 1e-9, start * 1e-9, end * 1e-9, n, topics,
                   start_ns=start, end_ns=last, offered_qos=qos)


def _storage_from_metadata(path: Path) -> str:
    meta = path / 'metadata.yaml'
    if meta.exists():
        m = re.search(r'storage_identifier:\s*(\S+)', meta.read_text())
        if m:
            return m.group(1)
    return 'unknown'
