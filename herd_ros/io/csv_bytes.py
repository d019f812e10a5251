"""CSV text built column-wise in numpy: the same characters as Python's ``'%.Nf' % v``.

Writing a trajectory CSV of 360 000 rows with Python's string formatting costs ~0.25 s,
most of it the float formatting of x and y, one value at a time. Here a float column is
turned into digits as integer arithmetic on the whole column (:func:`fixed_point`), the
fields of every row are laid side by side in a byte matrix, and the padding — zero bytes,
which no field holds — is dropped in one pass over the text (:func:`join_rows`).

Exactness: ``'%.Nf'`` rounds the exact binary value half-to-even. ``rint(|v|·10ᴺ)`` gives
the same integer unless the exact product lies within a rounding error of a half (or the
value is too large for the product's fraction to be resolved); those few values are
formatted by Python instead, so the text is always Python's.
"""
from __future__ import annotations

import numpy as np

_ZERO = ord('0')


def text_field(strings) -> tuple[np.ndarray, np.ndarray]:
    """A column of strings (UTF-8) as ``(bytes (n, W) uint8, mask (n, W))``, the mask
    marking each row's characters (the rest zero bytes; a string holding one is refused:
    :func:`join_rows` drops them)."""
    encoded = [s.encode() for s in strings]
    if any(b'\0' in b for b in encoded):
        raise ValueError('a text field holds a NUL character')
    lengths = np.fromiter((len(b) for b in encoded), np.int64, len(encoded))
    width = int(lengths.max(initial=0))
    buf = np.frombuffer(b''.join(b.ljust(width, b'\0') for b in encoded), np.uint8)
    return buf.reshape(len(encoded), width), np.arange(width) < lengths[:, None]


def fixed_point(values, decimals: int = 6) -> tuple[np.ndarray, np.ndarray]:
    """``'%.{decimals}f' % v`` for every value of a float column, as ``(bytes (n, W)
    uint8, mask (n, W))``, right-aligned. Non-finite values are formatted by Python."""
    v = np.asarray(values, dtype=float).reshape(-1)
    n = len(v)
    with np.errstate(invalid='ignore', over='ignore'):
        a = np.abs(v)
        scaled = a * 10.0 ** decimals
        frac = scaled - np.floor(scaled)
        python = ~np.isfinite(scaled) | (a >= 1e9) | (np.abs(frac - 0.5) < 1e-6)
    q = np.where(python, 0.0, np.rint(scaled)).astype(np.int64)
    ip, fp = np.divmod(q, 10 ** decimals)
    ndig = np.ones(n, np.int64)
    for k in range(1, 10):
        ndig += ip >= 10 ** k
    neg = np.signbit(v)
    lengths = neg + ndig + (1 + decimals if decimals else 0)
    special = np.flatnonzero(python)
    texts = [('%.*f' % (decimals, v[k])).encode() for k in special]
    width = int(max(lengths.max(initial=1), max((len(t) for t in texts), default=0)))
    out = np.zeros((n, width), np.uint8)
    col = width - 1
    for _ in range(decimals):                     # fraction digits, least significant first
        fp, digit = np.divmod(fp, 10)
        out[:, col] = _ZERO + digit
        col -= 1
    if decimals:
        out[:, col] = ord('.')
        col -= 1
    for k in range(int(ndig.max(initial=1))):     # integer digits (zero bytes beyond ndig)
        ip, digit = np.divmod(ip, 10)
        out[:, col] = np.where(ndig > k, _ZERO + digit, 0) if k else _ZERO + digit
        col -= 1
    rows = np.flatnonzero(neg)
    out[rows, width - lengths[rows]] = ord('-')
    for k, t in zip(special, texts):
        out[k] = 0
        out[k, width - len(t):] = np.frombuffer(t, np.uint8)
        lengths[k] = len(t)
    return out, np.arange(width) >= (width - lengths)[:, None]


def join_rows(fields, sep: bytes = b',', end: bytes = b'\n') -> bytes:
    """The CSV text of rows whose fields are ``(bytes, mask)`` columns (all of n rows,
    as :func:`text_field` and :func:`fixed_point` make them: zero bytes outside the mask,
    none inside; the masks are not read, and may be None): fields joined by ``sep``, each
    row ended by ``end``. The rows' byte matrix is written out and its zero bytes dropped
    by ``bytes.replace`` — a boolean mask of the whole matrix and its gather cost 2-5
    times as much, most of it faulting in the mask's fresh pages."""
    n = len(fields[0][0])
    blocks = []
    for k, (buf, _) in enumerate(fields):
        blocks.append(buf)
        tail = end if k == len(fields) - 1 else sep
        blocks.append(np.broadcast_to(np.frombuffer(tail, np.uint8), (n, len(tail))))
    return np.hstack(blocks).tobytes().replace(b'\0', b'')
