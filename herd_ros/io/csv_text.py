"""Check that a CSV file is what the readers expect before pandas sees it.

Every reader of the herd commands (trajectory CSV, GPS CSV, Movebank CSV) runs
:func:`check_csv_text` first, so a hostile file gets one line naming the file, the line and
what is wrong, instead of a traceback or a row silently dropped:

* not UTF-8 text (a binary file, or a CSV saved as Latin-1 / Windows-1252);
* empty, or a header only;
* another delimiter (``;``, tab) than the comma;
* a row with more or fewer fields than the header (a truncated last line, a stray comma).
"""
from __future__ import annotations

import csv
import io
from pathlib import Path

from herd_ros.errors import HerdInputError


def check_csv_text(path, chunk_lines: int = 200_000) -> int:
    """Raise :class:`HerdInputError` (one line) unless ``path`` is a comma-separated UTF-8
    file whose every non-empty row has the header's number of fields; returns the number of
    data rows."""
    path = Path(path)
    if not path.is_file():
        raise HerdInputError(f'{path}: no such file')
    raw = path.read_bytes()
    if b'\x00' in raw[:65536]:
        raise HerdInputError(f'{path}: a binary file, not a CSV (NUL bytes)')
    if raw.isascii() and b'"' not in raw:  # the common case: no decoding, no csv module
        end = raw.find(b'\n')
        width = raw[:end if end >= 0 else len(raw)].count(b',') + 1
        if width > 1:
            return _count_rows_unquoted(path, raw, width)
    try:
        text = raw.decode('utf-8-sig')
    except UnicodeDecodeError as exc:
        line = raw[:exc.start].count(b'\n') + 1
        raise HerdInputError(
            f'{path}: line {line}: byte 0x{raw[exc.start]:02x} is not UTF-8 text (a binary '
            f'file, or a CSV saved in another encoding such as Latin-1: save it as UTF-8)'
        ) from None
    if not text.strip():
        raise HerdInputError(f'{path}: empty file')
    reader = csv.reader(io.StringIO(text))
    header = next(reader)
    width = len(header)
    if width == 1:
        for sep, name in ((';', 'semicolons'), ('\t', 'tabs'), ('|', 'bars')):
            if sep in header[0]:
                raise HerdInputError(f'{path}: line 1: the fields are separated by {name}; '
                                     f'herd-ros reads comma-separated files')
    rows = 0
    for row in reader:
        if not row or (len(row) == 1 and not row[0].strip()):
            continue                       # blank line (pandas skips them too)
        rows += 1
        if len(row) != width:
            raise HerdInputError(
                f'{path}: line {reader.line_num}: {len(row)} field{"s" if len(row) != 1 else ""}'
                f', the header has {width} (a truncated or malformed row)')
    if rows == 0:
        raise HerdInputError(f'{path}: no data rows (a header only)')
    return rows


def _count_rows_unquoted(path, raw: bytes, width: int) -> int:
    """The row check of :func:`check_csv_text` for an ASCII file without quotes (no field
    can hold a comma or a line break): commas counted per line with numpy, ~20x faster
    than the csv module on large files."""
    import numpy as np

    b = np.frombuffer(raw, np.uint8)
    ends = np.flatnonzero(b == 10)
    if not len(ends) or ends[-1] != len(b) - 1:
        ends = np.r_[ends, len(b)]                 # a last line without a newline
    starts = np.r_[0, ends[:-1] + 1]
    commas = np.flatnonzero(b == 44)
    per_line = np.diff(np.searchsorted(commas, np.r_[starts, len(b) + 1]))
    odd = np.flatnonzero(per_line[1:] != width - 1) + 1
    rows = len(starts) - 1 - len(odd)
    for k in odd:
        if raw[starts[k]:ends[k]].strip():
            n = int(per_line[k]) + 1
            raise HerdInputError(
                f'{path}: line {k + 1}: {n} field{"s" if n != 1 else ""}, the header has '
                f'{width} (a truncated or malformed row)')
    if rows == 0:
        raise HerdInputError(f'{path}: no data rows (a header only)')
    return rows
