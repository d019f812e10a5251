"""The collar kernels compiled ahead of time: built at install, loaded without numba.

:mod:`herd_ros.ingest.collar_kernels` holds the loops of the collar bank and of the
streaming herd clock, written for numba. Compiled just in time, they cost every process
~0.5 s before its first fix, whatever the size of the data: importing numba (~0.2 s) and
loading its cached machine code (~0.3 s, most of it numba's target context, which imports
scipy's BLAS). For ``herd-ros ingest`` on a file of 360 000 fixes that is a third of the
whole run.

So ``setup.py`` also compiles the same functions ahead of time, with ``numba.pycc``, into
the extension module ``herd_ros.ingest._collar_kernels`` (:func:`compiler`): the same
source and the same LLVM, for the generic CPU of the platform. :func:`load_kernels` takes
that extension when it was built from the ``collar_kernels.py`` beside it (it carries a
digest of the sources, :func:`source_digest`) and numba otherwise; the results are the same
to the last bit on the test herds (``test/test_collar_kernels_aot.py``). Where the
extension could not be built (no C compiler at install) the JIT path runs, 0.5 s slower per
process. ``HERD_ROS_KERNELS=jit`` (or ``aot``) forces a path.

pycc's wrappers trust their arguments (a float32 array where float64 is declared crashes
the process, a strided view is read as contiguous), so :class:`AheadOfTime` checks every
argument against :data:`EXPORTS` before the call. This module itself imports neither
numba nor the kernels until asked.
"""
from __future__ import annotations

import hashlib
import os
import warnings
from pathlib import Path

import numpy as np

#: the extension module's name (in the package ``herd_ros.ingest``)
EXTENSION = '_collar_kernels'
#: the sources the extension is compiled from (its digest covers them)
SOURCES = ('collar_kernels.py', 'fix_outcomes.py', 'aot.py')
#: environment variable choosing the kernels: ``auto`` (default), ``aot`` or ``jit``
ENV = 'HERD_ROS_KERNELS'

#: The entry points of :mod:`~herd_ros.ingest.collar_kernels`: name -> (return type,
#: argument types). An argument type is a scalar (``'f8'`` float64, ``'i8'`` int64) or an
#: array ``(dtype, ndim, written)``, always C-contiguous; ``written`` marks the arrays the
#: kernel writes into.
EXPORTS = {
    'covariances': ('void', (('i8', 1, False), ('f8', 2, False), ('f8', 1, False),
                             ('f8', 1, False),
                             ('f8', 3, True))),
    'predict_many': ('void', (('f8', 2, False), ('f8', 3, False), ('f8', 1, False),
                              ('f8', 1, False), ('f8', 1, False), ('f8', 2, True),
                              ('f8', 3, True))),
    'predict_gathered': ('void', (('i8', 1, False), ('i8', 1, False), ('f8', 1, False),
                                  ('f8', 2, False), ('f8', 3, False), ('f8', 2, False),
                                  ('f8', 2, True), ('f8', 3, True))),
    'process_batch': ('void', (
        # the batch: collar, stamp, east, north, status, R
        ('i8', 1, False), ('f8', 1, False), ('f8', 1, False), ('f8', 1, False),
        ('i8', 1, False), ('f8', 3, False),
        # the bank: t, x, P, ever, last_pos, last_report, counters, n_cand, cand_jump,
        # cand_len, cand_t, cand_z, cand_r, range moments, left place
        ('f8', 1, True), ('f8', 2, True), ('f8', 3, True), ('b1', 1, True),
        ('f8', 1, True), ('f8', 1, True), ('i8', 2, True), ('i8', 1, True),
        ('b1', 2, True), ('i8', 2, True), ('f8', 3, True), ('f8', 4, True),
        ('f8', 5, True), ('f8', 2, True), ('f8', 2, True),
        # accel_std (N,), velocity_tau (N,), max_speed, cruise_speed, sprint_s, gate,
        # gate_sigma, v0, confirm, reacquire, confirm_lost, reinit_after_gap,
        # range_sigmas, range_margin, range_min
        ('f8', 1, False), ('f8', 1, False), 'f8', 'f8', 'f8', 'f8', 'f8', 'f8', 'i8', 'i8',
        'i8', 'f8', 'f8', 'f8', 'i8',
        # walk_accel (<= 0: none), walk_tau, walk_prob, walk_r2
        'f8', 'f8', 'f8', 'f8',
        # out: code, d2, x, P, segment
        ('i1', 1, True), ('f8', 1, True), ('f8', 2, True), ('f8', 3, True),
        ('i8', 1, True))),
    'rts_backward': ('void', (('b1', 1, False), ('f8', 2, False), ('f8', 2, False),
                              ('f8', 3, False), ('f8', 3, False), ('f8', 3, False),
                              ('f8', 2, True), ('f8', 3, True))),
    'record_states': ('i8', (('i8', 1, False), ('f8', 1, False), ('f8', 2, False),
                             ('f8', 3, False), ('f8', 2, False), 'f8', ('i8', 1, True),
                             ('f8', 2, True), ('f8', 3, True), ('f8', 4, True),
                             ('f8', 3, True))),
    'motion_loglik': ('void', (('f8', 2, False), ('f8', 3, False), ('f8', 2, False),
                               ('i8', 1, False), ('f8', 2, False), ('f8', 2, False),
                               ('f8', 2, False), 'f8', 'f8', 'f8', 'f8', 'f8',
                               ('f8', 2, True))),
    'motion_distance': ('void', (('f8', 2, False), ('f8', 3, False), ('f8', 2, False),
                                 ('i8', 1, False), ('f8', 2, False), ('f8', 2, False),
                                 ('f8', 2, False), 'f8', 'f8', 'f8', 'f8',
                                 ('f8', 3, True))),
    'motion_nelder_mead': ('void', (('f8', 2, False), ('f8', 3, False), ('f8', 2, False),
                                    ('i8', 1, False), ('f8', 2, False), ('f8', 2, False),
                                    ('f8', 2, False), ('f8', 2, False), 'f8', 'f8', 'f8',
                                    'f8', 'f8', ('i8', 1, False), 'f8', ('f8', 2, True),
                                    ('f8', 1, True))),
    'snapshot': ('void', ('f8', ('i8', 1, False), ('f8', 2, False), ('f8', 3, False),
                          ('f8', 4, False), ('f8', 3, False), 'f8', ('f8', 2, True),
                          ('f8', 3, True), ('b1', 1, True), ('b1', 1, True))),
}


def signature(name: str) -> str:
    """The numba signature string of entry point ``name`` (for ``numba.pycc``)."""
    ret, args = EXPORTS[name]
    text = [a if isinstance(a, str) else f'{a[0]}[{", ".join([":"] * (a[1] - 1) + ["::1"])}]'
            for a in args]
    return f'{ret}({", ".join(text)})'


_DTYPES = {'f8': np.dtype(np.float64), 'i8': np.dtype(np.int64), 'i1': np.dtype(np.int8),
           'b1': np.dtype(np.bool_)}
_SCALARS = {'f8': float, 'i8': int}


def source_digest() -> int:
    """A 60-bit digest of :data:`SOURCES` as they are on disk beside this module."""
    h = hashlib.sha256()
    here = Path(__file__).resolve().parent
    for name in SOURCES:
        h.update((here / name).read_bytes())
    return int(h.hexdigest()[:15], 16)


class Kernels:
    """The entry points of :data:`EXPORTS` as attributes (``covariances``,
    ``predict_many``, ``predict_gathered``, ``process_batch``, ``record_states``,
    ``snapshot``, the motion fit's) and ``kind``:
    ``'aot'`` or ``'jit'``."""

    def __init__(self, kind: str, functions: dict):
        self.kind = kind
        for name, fn in functions.items():
            setattr(self, name, fn)

    def __repr__(self):
        return f'<collar kernels: {self.kind}>'


def _checked(name: str, fn, spec):
    """``fn`` (a pycc entry point) behind a check of every argument against ``spec``."""
    _, args = spec

    def call(*values):
        if len(values) != len(args):
            raise TypeError(f'{name} takes {len(args)} arguments, got {len(values)}')
        out = []
        for k, (v, a) in enumerate(zip(values, args)):
            if isinstance(a, str):
                out.append(_SCALARS[a](v))
                continue
            dtype, ndim, written = a
            if not (isinstance(v, np.ndarray) and v.dtype == _DTYPES[dtype]
                    and v.ndim == ndim and v.flags.c_contiguous
                    and (v.flags.writeable or not written)):
                got = (f'{v.dtype}, {v.ndim}-d, '
                       f'{"" if v.flags.c_contiguous else "not "}C-contiguous'
                       f'{"" if v.flags.writeable else ", read-only"}'
                       if isinstance(v, np.ndarray) else type(v).__name__)
                raise TypeError(f'{name}: argument {k} must be a C-contiguous '
                                f'{"writable " if written else ""}{ndim}-d {_DTYPES[dtype]} '
                                f'array, got {got}')
            out.append(v)
        return fn(*out)

    call.__name__ = name
    call.__doc__ = f'{name} of the ahead-of-time compiled collar kernels (arguments checked).'
    return call


class AheadOfTime(Kernels):
    """The extension module's entry points, each behind an argument check; ``module`` is
    the extension itself."""

    def __init__(self, module):
        self.module = module
        super().__init__('aot', {name: _checked(name, getattr(module, name), spec)
                                 for name, spec in EXPORTS.items()})


def _extension():
    """The built extension module if importable and built from these sources, else None
    (with a warning when it is stale)."""
    try:
        from herd_ros.ingest import _collar_kernels as ext
    except ImportError:
        return None
    if ext.source_digest() != source_digest():
        warnings.warn(f'{ext.__file__} was built from other sources than '
                      f'{", ".join(SOURCES)}; using numba instead (reinstall herd_ros to '
                      f'rebuild it)', RuntimeWarning, stacklevel=3)
        return None
    return ext


def load_kernels(kind: str | None = None) -> Kernels | None:
    """The collar kernels this process runs.

    Args:
        kind: ``'aot'``, ``'jit'`` or ``'auto'`` (the extension if built from these
            sources, else numba); None reads :data:`ENV` (default ``auto``).

    Returns:
        :class:`Kernels`, or None in ``auto`` when neither the extension nor numba is
        present (callers then use the reference filter).
    """
    kind = (os.environ.get(ENV) or 'auto') if kind is None else kind
    if kind not in ('auto', 'aot', 'jit'):
        raise ValueError(f'{ENV} must be auto, aot or jit, got {kind!r}')
    if kind != 'jit':
        ext = _extension()
        if ext is not None:
            return AheadOfTime(ext)
        if kind == 'aot':
            raise ImportError(f'herd_ros.ingest.{EXTENSION} is not built (or stale); it is '
                              f'compiled when herd_ros is installed with numba and a C '
                              f'compiler present')
    try:
        from herd_ros.ingest import collar_kernels
    except ModuleNotFoundError as exc:
        if kind == 'jit' or exc.name != 'numba':
            raise
        return None
    return Kernels('jit', {name: getattr(collar_kernels, name) for name in EXPORTS})


def _release_the_gil():
    """Make ``numba.pycc`` compile entry points whose Python wrappers release the GIL, as
    the JIT path's ``nogil=True`` does. pycc builds every export with a default
    ``numba.core.compiler.Flags`` (``release_gil`` off) and has no option for it, so its
    module's ``Flags`` is replaced, in the compiling process only, by one with
    ``release_gil`` on. The kernels touch only the arrays they are given, so threads may
    call them at once on disjoint collars (:mod:`herd_ros.ingest.collar_threads`)."""
    import numba.pycc.compiler as pycc_compiler
    base = pycc_compiler.Flags
    if getattr(base, 'releases_gil', False):
        return

    class ReleasingFlags(base):
        releases_gil = True

        def __init__(self, *args, **kwargs):
            super().__init__(*args, **kwargs)
            self.release_gil = True

    pycc_compiler.Flags = ReleasingFlags


def compiler(output_dir: str | None = None):
    """A ``numba.pycc.CC`` for the extension: every entry point of :data:`EXPORTS` with its
    signature, and ``source_digest() -> int64``, the :func:`source_digest` of the sources
    compiled. ``setup.py`` turns it into an extension (``CC.distutils_extension``); tests
    compile it into a temporary directory (``CC.compile``)."""
    with warnings.catch_warnings():         # pycc is "pending deprecation" (no replacement)
        warnings.simplefilter('ignore')
        from numba.pycc import CC
    _release_the_gil()
    from herd_ros.ingest import collar_kernels

    cc = CC(EXTENSION)
    if output_dir is not None:
        cc.output_dir = str(output_dir)
    for name in EXPORTS:
        cc.export(name, signature(name))(getattr(collar_kernels, name).py_func)
    digest = source_digest()

    def digest_of_sources():
        return digest

    cc.export('source_digest', 'i8()')(digest_of_sources)
    return cc
