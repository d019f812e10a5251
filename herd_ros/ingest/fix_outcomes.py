"""The codes the compiled collar filter speaks in: what happened to a fix, and where each
collar counts it.

Shared by :mod:`herd_ros.ingest.collar_kernels` (the compiled loops, which read them as
constants) and :mod:`herd_ros.ingest.collar_bank` (which names them), without importing a
compiler. The names are those of the reference filter
(:class:`~herd_ros.ingest.collar_filter.FixResult` reasons and
:data:`~herd_ros.ingest.collar_filter.COUNTERS`).
"""
from herd_ros.ingest.collar_filter import COUNTERS, STATUS_NO_FIX, CollarFilter

#: outcome codes of :meth:`~herd_ros.ingest.collar_bank.CollarBank.process`, indices into
#: this tuple (the reasons of :class:`~herd_ros.ingest.collar_filter.FixResult`)
OUTCOMES = ('accepted', 'reinitialised', 'no_fix', 'nan', 'time', 'gate', 'speed',
            'unconfirmed', 'range')
ACCEPTED, REINITIALISED, NO_FIX, NAN, TIME, GATE, SPEED, UNCONFIRMED, RANGE = range(9)

#: open candidate chains per collar
MAX_CANDIDATES = CollarFilter.MAX_CANDIDATES

#: counter columns, in COUNTERS order
C_ACC, C_NO_FIX, C_NAN, C_TIME, C_GATE, C_SPEED, C_RANGE, C_UNCONF, C_REINIT = range(9)
assert COUNTERS == ('accepted', 'rejected_no_fix', 'rejected_nan', 'rejected_time',
                    'rejected_gate', 'rejected_speed', 'rejected_range',
                    'rejected_unconfirmed', 'reinitialised')

__all__ = ['COUNTERS', 'STATUS_NO_FIX', 'OUTCOMES', 'MAX_CANDIDATES', 'ACCEPTED',
           'REINITIALISED', 'NO_FIX', 'NAN', 'TIME', 'GATE', 'SPEED', 'UNCONFIRMED', 'RANGE',
           'C_ACC', 'C_NO_FIX', 'C_NAN', 'C_TIME', 'C_GATE', 'C_SPEED', 'C_RANGE', 'C_UNCONF',
           'C_REINIT']
