"""Readers of GPS fix files into one *fixes table* (a pandas DataFrame).

The fixes table has one row per fix and the columns :data:`FIX_COLUMNS`:

=========================== ======================================================
``time``                    epoch seconds (UTC), float
``agent``                   collar / animal id, str
``lat``, ``lon``            WGS84 degrees (NaN for a row without a position)
``alt``                     metres above the ellipsoid, NaN when unknown
``status``                  NavSatStatus.status (0 = FIX, -1 = NO_FIX)
``position_covariance_type`` NavSatFix covariance type (0 = UNKNOWN)
``cov_ee, cov_en, cov_nn``  E/N block of ``position_covariance`` (m²), NaN if unknown
=========================== ======================================================

and, where the file gives it, ``hdop`` (the fix's horizontal dilution of precision, NaN where
a row has none): a fix without a covariance then has the std σ_m·HDOP, σ_m fitted per collar
(:mod:`herd_ros.ingest.motion_fit`).

Formats:

* **GPS CSV** (doc/formats.md): header ``time,agent,lat,lon`` with optional ``alt`` (and the other
  columns above, and ``hdop``); ``time`` in epoch seconds or ISO-8601 (naive times are taken
  as UTC).
* **Movebank CSV**: ``timestamp`` (UTC, ``YYYY-MM-DD HH:MM:SS[.fff]``), ``location-long``,
  ``location-lat``, ``individual-local-identifier``; ``height-above-ellipsoid`` and
  ``gps:hdop`` if present.
  Rows without a location stay in the table with NaN lat/lon (the filter counts them).
* **GPX** 1.0/1.1: every ``trk`` is one agent, named by its ``<name>`` or else by the file
  name (``<stem>`` or ``<stem>_<k>`` for several tracks); ``trkpt`` lat/lon, ``ele``, ``time``,
  ``hdop``.

Errors raise :class:`herd_ros.errors.HerdInputError` naming the file, line and field.
"""
from __future__ import annotations

import warnings
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pandas as pd

from herd_ros.agent_ids import ros_agent_id_column
from herd_ros.errors import HerdInputError, InputNote

FIX_COLUMNS = ('time', 'agent', 'lat', 'lon', 'alt', 'status', 'position_covariance_type',
               'cov_ee', 'cov_en', 'cov_nn')
MOVEBANK_COLUMNS = ('timestamp', 'location-long', 'location-lat',
                    'individual-local-identifier')


#: other names a GPS CSV's columns go by (compared without case): a column missing under
#: its own name is taken under one of these, and the reader says so (not ``alt``: a
#: logger's altitude is often above the geoid, the GPS CSV's above the ellipsoid)
GPS_ALIASES = {
    'time': ('timestamp', 'datetime', 'date_time', 'time_utc', 'utc'),
    'agent': ('id', 'animal', 'animal_id', 'individual', 'collar', 'collar_id', 'tag',
              'tag_id', 'device', 'device_id'),
    'lat': ('latitude',),
    'lon': ('longitude', 'long', 'lng'),
}


def gps_columns(path, header) -> dict:
    """{column in the file: its GPS CSV name} for the columns of :data:`GPS_ALIASES` the
    file gives under another name (only where the GPS CSV name itself is absent; compared
    without case); one clear error when two of its columns could be the same one."""
    cols = [str(c).strip() for c in header]
    present = {c.lower() for c in cols}
    out = {}
    for name, aliases in GPS_ALIASES.items():
        if name in present:
            continue
        hits = [c for c in cols if c.lower() == name or c.lower() in aliases]
        if len(hits) > 1:
            _fail(path, f'columns {", ".join(repr(h) for h in hits)} could each be the '
                        f'{name!r} column; rename the one that is to {name!r}')
        if hits and hits[0] != name:
            out[hits[0]] = name
    return out


def normalise_fixes(df: pd.DataFrame) -> pd.DataFrame:
    """Add the optional columns with their defaults and fix the dtypes (a table that is
    already a fixes table, as every reader returns, is returned as it is: no copy)."""
    if _is_fixes_table(df):
        return df
    out = df.copy()
    defaults = {'alt': np.nan, 'status': 0, 'position_covariance_type': 0,
                'cov_ee': np.nan, 'cov_en': np.nan, 'cov_nn': np.nan}
    for col, value in defaults.items():
        if col not in out.columns:
            out[col] = value
    out['agent'] = out['agent'].astype(str)
    for col in ('time', 'lat', 'lon', 'alt', 'cov_ee', 'cov_en', 'cov_nn'):
        out[col] = out[col].astype(float)
    for col in ('status', 'position_covariance_type'):
        out[col] = out[col].fillna(0).astype(int)
    if 'hdop' in out.columns:
        out['hdop'] = out['hdop'].astype(float)
    cols = list(FIX_COLUMNS) + [c for c in out.columns if c not in FIX_COLUMNS]
    return out[cols].reset_index(drop=True)


def _is_fixes_table(df: pd.DataFrame) -> bool:
    """``df`` has exactly :data:`FIX_COLUMNS`, in order, with their dtypes (agent ids as
    str), and the default index: what :func:`normalise_fixes` makes."""
    if tuple(df.columns) != FIX_COLUMNS or not isinstance(df.index, pd.RangeIndex):
        return False
    if df.index.start != 0 or df.index.step != 1:
        return False
    kinds = dict(zip(df.columns, df.dtypes))
    if any(kinds[c] != np.float64 for c in ('time', 'lat', 'lon', 'alt', 'cov_ee', 'cov_en',
                                            'cov_nn')):
        return False
    if any(kinds[c] != np.int64 for c in ('status', 'position_covariance_type')):
        return False
    return (kinds['agent'] == _STR_DTYPE
            and pd.api.types.infer_dtype(df['agent'], skipna=False) in ('string', 'empty'))


#: the dtype ``astype(str)`` gives (object before pandas 3, a string dtype from it)
_STR_DTYPE = pd.Series(['x'], dtype=object).astype(str).dtype


from herd_ros.io.csv_text import check_csv_text  # noqa: E402


def _fail(path, msg):
    raise HerdInputError(f'{path}: {msg}')


def _read_csv(path, text_columns=()) -> pd.DataFrame:
    """The CSV after :func:`check_csv_text`; numeric columns parsed by pandas' C reader
    (a column with any text left as strings, which :func:`_numeric` and
    :func:`parse_times` then check cell by cell); ``text_columns`` always as strings."""
    path = Path(path)
    check_csv_text(path)
    try:
        header = pd.read_csv(path, nrows=0, skipinitialspace=True).columns
        wanted = {t.lower() for t in text_columns}
        text = {c: str for c in header if str(c).strip().lower() in wanted}
        df = pd.read_csv(path, dtype=text, skipinitialspace=True, keep_default_na=True)
    except Exception as exc:
        _fail(path, f'not a readable CSV ({exc.__class__.__name__}: {exc})'.splitlines()[0])
    df.columns = [str(c).strip() for c in df.columns]
    if len(df) == 0:
        _fail(path, 'no data rows')
    return df


def _numeric(path, df, col, *, allow_nan: bool, out_name: str | None = None):
    """Column ``col`` as floats; a non-number (or NaN when not allowed) names its line."""
    raw = df[col]
    if pd.api.types.is_numeric_dtype(raw) and not pd.api.types.is_bool_dtype(raw):
        values = raw.to_numpy(dtype=float)
        bad = np.zeros(len(values), bool) if allow_nan else ~np.isfinite(values)
        if bad.any():
            k = int(np.argmax(bad))
            _fail(path, f'line {k + 2}: {out_name or col} is {raw.iloc[k]!r}, not a number')
        return values
    raw = raw.astype(object).where(raw.notna(), None)
    values = pd.to_numeric(raw, errors='coerce').to_numpy(dtype=float)
    bad = np.isnan(values) & raw.notna().to_numpy() if allow_nan else ~np.isfinite(values)
    if allow_nan:
        # a written value that is not a number (empty cells and 'nan' are fine)
        text = raw.fillna('').astype(str).str.strip().str.lower()
        bad &= ~text.isin(['', 'nan'])
    if bad.any():
        k = int(np.argmax(bad))
        _fail(path, f'line {k + 2}: {out_name or col} is {raw.iloc[k]!r}, not a number')
    return values


def parse_times(path, raw: pd.Series, field: str = 'time') -> np.ndarray:
    """Epoch seconds from epoch numbers or ISO-8601 strings (naive = UTC)."""
    if not (pd.api.types.is_numeric_dtype(raw) and not pd.api.types.is_bool_dtype(raw)):
        raw = raw.astype(object).where(raw.notna(), None)
    numeric = pd.to_numeric(raw, errors='coerce')
    values = numeric.to_numpy(dtype=float, copy=True)
    text = ~numeric.notna().to_numpy()
    if text.any():
        # ISO-8601 element by element, so one bad cell is named, not the whole column
        stamps = pd.to_datetime(raw[text], utc=True, errors='coerce', format='ISO8601')
        seconds = (stamps - pd.Timestamp('1970-01-01', tz='UTC')).dt.total_seconds()
        values[text] = seconds.to_numpy(dtype=float)
    bad = ~np.isfinite(values)
    if bad.any():
        k = int(np.argmax(bad))
        _fail(path, f'line {k + 2}: {field} is {raw.iloc[k]!r}, neither epoch seconds nor '
                    f'an ISO-8601 time')
    bad = ~np.isfinite(values)
    if bad.any():
        k = int(np.argmax(bad))
        _fail(path, f'line {k + 2}: {field} is {raw.iloc[k]!r}, not a time')
    return values


def read_gps_csv(path) -> pd.DataFrame:
    """A GPS CSV (``time,agent,lat,lon[,alt]``; the columns also under the names of
    :data:`GPS_ALIASES`, said in an :class:`~herd_ros.errors.InputNote`) as a fixes
    table."""
    df = _read_csv(path, text_columns=('agent',) + GPS_ALIASES['agent'])
    renamed = gps_columns(path, df.columns)
    if renamed:
        df = df.rename(columns=renamed)
        warnings.warn(InputNote(f'{path}: column{"s" if len(renamed) > 1 else ""} '
                                + ', '.join(f'{c!r} read as {n!r}' for c, n in renamed.items())),
                      stacklevel=2)
    missing = [c for c in ('time', 'agent', 'lat', 'lon') if c not in df.columns]
    if missing:
        _fail(path, f'missing column(s) {", ".join(missing)}; a GPS CSV needs the header '
                    f'time,agent,lat,lon[,alt] (got {",".join(df.columns)})')
    empty = df['agent'].isna().to_numpy()
    if empty.any():
        _fail(path, f'line {int(np.argmax(empty)) + 2}: empty agent')
    out = pd.DataFrame({'time': parse_times(path, df['time']), 'agent': _ids(df['agent'], path)})
    for col in ('lat', 'lon'):
        out[col] = _numeric(path, df, col, allow_nan=True)
    _check_ranges(path, out)
    for col in ('alt', 'cov_ee', 'cov_en', 'cov_nn', 'status', 'position_covariance_type',
                'hdop'):
        if col in df.columns:
            out[col] = _numeric(path, df, col, allow_nan=True)
    return normalise_fixes(out)


def _ids(raw: pd.Series, path) -> np.ndarray:
    """Agent ids, stripped and made ROS name tokens
    (:func:`~herd_ros.agent_ids.ros_agent_id_column`)."""
    return ros_agent_id_column(raw, str(path))


def _check_ranges(path, out, lat='lat', lon='lon'):
    for col, name, limit in (('lat', lat, 90.0), ('lon', lon, 180.0)):
        v = out[col].to_numpy()
        bad = np.abs(v) > limit
        if bad.any():
            k = int(np.argmax(bad))
            _fail(path, f'line {k + 2}: {name} is {float(v[k]):g}, outside ±{limit:g} degrees')


def read_movebank_csv(path) -> pd.DataFrame:
    """A Movebank export (``timestamp, location-long, location-lat,
    individual-local-identifier``) as a fixes table."""
    df = _read_csv(path, text_columns=('individual-local-identifier', 'timestamp'))
    missing = [c for c in MOVEBANK_COLUMNS if c not in df.columns]
    if missing:
        _fail(path, f'missing Movebank column(s) {", ".join(missing)}')
    empty = df['individual-local-identifier'].isna().to_numpy()
    if empty.any():
        _fail(path, f'line {int(np.argmax(empty)) + 2}: empty individual-local-identifier')
    out = pd.DataFrame({'time': parse_times(path, df['timestamp'], 'timestamp'),
                        'agent': _ids(df['individual-local-identifier'], path)})
    out['lat'] = _numeric(path, df, 'location-lat', allow_nan=True)
    out['lon'] = _numeric(path, df, 'location-long', allow_nan=True)
    _check_ranges(path, out, 'location-lat', 'location-long')
    if 'height-above-ellipsoid' in df.columns:
        out['alt'] = _numeric(path, df, 'height-above-ellipsoid', allow_nan=True)
    if 'gps:hdop' in df.columns:
        out['hdop'] = _numeric(path, df, 'gps:hdop', allow_nan=True)
    return normalise_fixes(out)


def read_gpx(path) -> pd.DataFrame:
    """GPX tracks as a fixes table (one agent per ``trk``)."""
    path = Path(path)
    if not path.is_file():
        _fail(path, 'no such file')
    try:
        tree = ET.parse(path)
    except ET.ParseError as exc:
        _fail(path, f'not valid XML ({exc})')
    root = tree.getroot()
    ns = root.tag[1:root.tag.index('}')] if root.tag.startswith('{') else ''
    q = (lambda tag: f'{{{ns}}}{tag}') if ns else (lambda tag: tag)
    if root.tag != q('gpx'):
        _fail(path, f'root element is {root.tag!r}, not gpx')
    tracks = root.findall(q('trk'))
    if not tracks:
        _fail(path, 'no <trk> track in the GPX file')
    rows = []
    for k, trk in enumerate(tracks):
        name = (trk.findtext(q('name')) or '').strip()
        if not name:
            name = path.stem if len(tracks) == 1 else f'{path.stem}_{k + 1}'
        for j, pt in enumerate(trk.iter(q('trkpt'))):
            where = f'track {name!r} point {j + 1}'
            try:
                lat, lon = float(pt.attrib['lat']), float(pt.attrib['lon'])
            except (KeyError, ValueError):
                _fail(path, f'{where}: lat/lon attribute missing or not a number')
            ele = pt.findtext(q('ele'))
            time = pt.findtext(q('time'))
            if time is None:
                _fail(path, f'{where}: no <time>')
            hdop = pt.findtext(q('hdop'))
            try:
                hdop = float(hdop) if hdop not in (None, '') else np.nan
            except ValueError:
                _fail(path, f'{where}: <hdop> is not a number')
            rows.append((time.strip(), name, lat, lon,
                         float(ele) if ele not in (None, '') else np.nan, hdop))
    if not rows:
        _fail(path, 'no <trkpt> points in the GPX tracks')
    raw = pd.DataFrame(rows, columns=['time', 'agent', 'lat', 'lon', 'alt', 'hdop'])
    raw['agent'] = _ids(raw['agent'], path)
    if not np.isfinite(raw['hdop'].to_numpy()).any():
        raw = raw.drop(columns='hdop')
    out = raw.copy()
    try:
        stamps = pd.to_datetime(raw['time'], utc=True, format='ISO8601')
    except (ValueError, TypeError):
        _fail(path, 'a <time> is not ISO-8601')
    out['time'] = (stamps - pd.Timestamp('1970-01-01', tz='UTC')).dt.total_seconds()
    _check_ranges(path, out)
    return normalise_fixes(out)


def sniff_format(path) -> str:
    """``'bag'``, ``'gpx'``, ``'movebank'`` or ``'gps'`` from the file name and header."""
    path = Path(path)
    if path.is_dir() or path.suffix.lower() in ('.mcap', '.db3'):
        return 'bag'
    if path.suffix.lower() == '.gpx':
        return 'gpx'
    if not path.is_file():
        _fail(path, 'no such file or bag')
    with open(path, 'rb') as fh:
        start = fh.read(4096)
    if b'\x00' in start:
        _fail(path, 'a binary file, not a CSV, GPX or bag (NUL bytes)')
    try:
        head = start.decode('utf-8-sig').splitlines()[0] if start.strip() else ''
    except UnicodeDecodeError:
        check_csv_text(path)               # names the line and the byte
        head = ''
    if not head.strip():
        _fail(path, 'empty file')
    if head.lstrip().startswith('<'):
        return 'gpx'
    names = [c.strip().strip('"') for c in head.strip().split(',')]
    cols = set(names)
    if {'location-long', 'location-lat'} <= cols:
        return 'movebank'
    if {'time', 'agent', 'lat', 'lon'} <= cols | set(gps_columns(path, names).values()):
        return 'gps'
    if ',' not in head:
        for sep, name in ((';', 'semicolons'), ('\t', 'tabs'), ('|', 'bars')):
            if sep in head:
                _fail(path, f'line 1: the fields are separated by {name}; herd-ros reads '
                            f'comma-separated files')
    if {'time', 'agent', 'x', 'y'} <= cols:
        _fail(path, 'a trajectory CSV of planar positions (x, y in metres), not GPS fixes: '
                    'fit, ingest, predict and report read it; import needs latitude/longitude')
    _fail(path, f'cannot tell the format: header {head.strip()[:80]!r} is neither a GPS CSV '
                f'(time,agent,lat,lon[,alt]) nor a Movebank CSV')


READERS = {'gps': read_gps_csv, 'movebank': read_movebank_csv, 'gpx': read_gpx}


def read_fix_file(path, fmt: str = 'auto') -> pd.DataFrame:
    """Read a GPS CSV, Movebank CSV or GPX file (``fmt`` 'auto' sniffs it)."""
    fmt = sniff_format(path) if fmt == 'auto' else fmt
    if fmt not in READERS:
        _fail(path, f'format {fmt!r} is not one of gps, movebank, gpx')
    return READERS[fmt](path)
