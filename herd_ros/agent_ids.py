"""Agent ids as ROS name tokens, made so where the data are read.

An agent id becomes part of topic and parameter names (``/herd/<id>/fix``,
``agents.<id>.damping``), and a ROS 2 name token has ASCII letters, digits and underscores
and does not start with a digit (rcl's ``rcl_validate_topic_name``: "topic name token must
not start with a number"). Real collars are often named otherwise: by serial number
(``4262``), with a dash or a space (``4262-84830876``, ``Cow 12``). Rather than accept such
a file in ``ingest`` and refuse its track in ``fit`` (or write a bag whose topics no ROS
node can open), the readers map every id through :func:`ros_agent_id`, the same way in every
verb (so a model fitted on a file predicts on the same file), and say which ids they
renamed (:class:`AgentIdsRenamed`, printed by the command line as a note). Two ids that
would become one are refused with one clear error: nothing is merged.

Plain Python; no ROS.
"""
from __future__ import annotations

import re
import warnings

from herd_ros.errors import HerdInputError, InputNote

#: a valid ROS name token (what :func:`ros_agent_id` returns)
ROS_TOKEN = re.compile(r'^[A-Za-z][A-Za-z0-9_]*$')
#: put before an id that does not start with a letter
PREFIX = 'id_'
#: at most this many renamed ids are spelled out in the note
NOTE_MAX = 6


class AgentIdsRenamed(InputNote):
    """Some agent ids of a file were not ROS name tokens and were renamed."""


def ros_agent_id(raw) -> str:
    """``raw`` (stripped) if it is a ROS name token; else every character other than an
    ASCII letter, digit or underscore replaced by ``_``, and :data:`PREFIX` put before it
    unless it then starts with a letter: ``Cow 12`` → ``Cow_12``, ``4262-8483`` →
    ``id_4262_8483``, ``1_CPS4`` → ``id_1_CPS4``."""
    text = str(raw).strip()
    if ROS_TOKEN.match(text):
        return text
    token = re.sub(r'[^A-Za-z0-9_]', '_', text)
    if not (token[:1].isascii() and token[:1].isalpha()):
        token = PREFIX + token
    return token


def ros_agent_ids(ids, where: str) -> list[str]:
    """Each distinct id of ``ids`` (a sequence of str) mapped by :func:`ros_agent_id`, in
    order; warns :class:`AgentIdsRenamed` (naming ``where``, the file) when any changed.

    Raises:
        HerdInputError: two ids that map to one name (say ``Cow 12`` and ``Cow_12``).
    """
    ids = [str(a).strip() for a in ids]
    mapped = [ros_agent_id(a) for a in ids]
    seen: dict[str, str] = {}
    for raw, new in zip(ids, mapped):
        if new in seen and seen[new] != raw:
            raise HerdInputError(f'{where}: agent ids {seen[new]!r} and {raw!r} would both '
                                 f'become {new!r} (a ROS name has letters, digits and '
                                 f'underscores, starting with a letter): rename one of them')
        seen[new] = raw
    renamed = [(raw, new) for raw, new in zip(ids, mapped) if raw != new]
    if renamed:
        shown = ', '.join(f'{raw!r} -> {new!r}' for raw, new in renamed[:NOTE_MAX])
        more = f' and {len(renamed) - NOTE_MAX} more' if len(renamed) > NOTE_MAX else ''
        warnings.warn(AgentIdsRenamed(
            f'{where}: {len(renamed)} agent id{"s" if len(renamed) != 1 else ""} made valid '
            f'ROS names (letters, digits and underscores, starting with a letter): '
            f'{shown}{more}'), stacklevel=2)
    return mapped


def ros_agent_id_column(values, where: str):
    """A column of ids (any sequence; a herd has few ids and many rows) as an object array
    of :func:`ros_agent_ids`, each distinct id mapped once."""
    import numpy as np
    import pandas as pd
    codes, uniques = pd.factorize(np.asarray(values, dtype=object), use_na_sentinel=False)
    return np.array(ros_agent_ids(uniques, where), dtype=object)[codes]
