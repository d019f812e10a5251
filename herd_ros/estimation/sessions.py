"""Estimator sessions (issue 26): data time far behind what was learned means a new
session — the same recording launched again, a looping replay, another herd. What was
learned belongs to the old session: its checkpoint is set aside, never deleted."""
from __future__ import annotations

import os


def set_aside(path: str) -> str:
    """Rename the checkpoint ``path`` to ``<root>.session-<k><ext>`` (the first free k) and
    return that name; '' when there is no checkpoint (or no path)."""
    if not path or not os.path.isfile(path):
        return ''
    root, ext = os.path.splitext(path)
    k = 1
    while os.path.exists(f'{root}.session-{k}{ext}'):
        k += 1
    aside = f'{root}.session-{k}{ext}'
    os.replace(path, aside)
    return aside
