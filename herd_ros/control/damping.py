"""The rule a learned damping must meet before robots follow the law (the controller's
check of every model it adopts, from a file or live from the estimator)."""
from __future__ import annotations

import numpy as np


#: The controller's rule for a learned damping a (see :func:`damping_check`).
DAMPING_RULE = ('|a| >= 1 is refused: the law is unstable (speeds grow without bound); '
                '-1 < a < 0 is followed with a warning: the velocity reverses sign every step, '
                'which no animal does, but a fit on positions with GPS noise at a coarse '
                'clock learns it (differenced noise is anti-correlated), and it is the best '
                'one-step law for that data')


def damping_check(dampings, agents) -> tuple[str | None, str | None]:
    """(refusal, warning) for a model's dampings under :data:`DAMPING_RULE`.

    The velocity recursion v(t+1) = a·v(t) + ... is stable only for |a| < 1 and decays
    without oscillating only for 0 <= a < 1.
    """
    a = np.asarray(dampings, dtype=float)
    unstable = ~(np.abs(a) < 1.0)                   # NaN counts as unstable
    if unstable.any():
        k = int(np.argmax(unstable))
        return (f'damping {a[k]:.3f} of {agents[k]} makes the law unstable (|a| >= 1)'
                + (f'; {int(unstable.sum())} agents in all' if unstable.sum() > 1 else ''),
                None)
    negative = a < 0.0
    if negative.any():
        names = ', '.join(f'{agents[k]} {a[k]:.3f}' for k in np.flatnonzero(negative)[:5])
        return None, (f'negative damping ({names}'
                      + (', ...' if negative.sum() > 5 else '') + '): the law reverses those '
                      'velocities every step (usually position noise at a coarse clock); '
                      'following it')
    return None, None
