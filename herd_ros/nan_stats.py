"""NaN-aware statistics without numpy's warnings: an agent absent from every step of a run
(a collar that never reported in that part of the data) has NaN statistics, which is the
answer, not a reason for "Mean of empty slice" on the user's terminal."""
from __future__ import annotations

import contextlib
import warnings

import numpy as np


@contextlib.contextmanager
def empty_slices_quiet():
    """numpy's nan-reductions inside give NaN for an all-NaN slice, silently."""
    with warnings.catch_warnings(), np.errstate(invalid='ignore', divide='ignore'):
        warnings.simplefilter('ignore', RuntimeWarning)
        yield
