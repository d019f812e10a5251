"""One parameter table per node: what each parameter is, declared, checked and shown from
one place (issue 26; the idea of generate_parameter_library, without a C++ toolchain).

A node's table (``herd_ros.params.<node>.TABLE``) lists its parameters as :class:`Param`:
default, a one-line description (the ROS descriptor's, ``ros2 param describe``), range or
choices, live or read-only, and the longer text shown above it in ``config/<node>.yaml``.
From the table

* the node declares its parameters with descriptors
  (:func:`herd_ros.nodes.ros_common.declare_parameters`) and checks every value against its
  type, range and choices at start and on ``ros2 param set`` (:func:`problem`) before its
  own checks (those the table cannot say, such as "an even number of values");
* :func:`render_yaml` writes ``config/<node>.yaml``; ``test/test_parameter_files.py`` fails
  when a shipped file is not what its table renders (``herd-ros params --write`` updates
  them);
* :func:`markdown_table` renders the documentation's table.

No rclpy here: the command line and the documentation read the tables without ROS.
"""
from __future__ import annotations

import importlib
import math
from dataclasses import dataclass, field

#: the nodes with a table, in the order the documentation lists them
NODES = ('gps_ingest', 'estimator', 'controller', 'fleet_sim', 'herd_sim', 'replay', 'record')

_UNSET = object()


class ParameterError(ValueError):
    """A parameter value a node cannot run with; the message names the parameter."""


@dataclass(frozen=True)
class Param:
    """One node parameter: its default, what it means, and whether it may change live.

    ``default`` is a value, declared with dynamic typing (so ``1`` is accepted for ``1.0``;
    an empty list default keeps ``ros2 param get`` working, where a typed array without a
    default answers nothing). Its type is the parameter's type (a float default takes any
    finite number; an int default an integer; a list, a list). ``range`` (lo, hi) is closed;
    an open bound (a std that must be > 0) is the node's own check. A parameter that is not
    ``live`` is read-only: read once at start, so ``ros2 param set`` is refused rather than
    answered "successful" and ignored.

    Shown in ``config/<node>.yaml``: ``doc`` above the entry (its lines become comments; a
    leading empty line leaves a blank line), the entry set to ``example`` when given (the
    file shows a working setup, e.g. three collar ids, where the default is empty), commented
    out when ``commented`` (a list that is empty by default, which a parameters file cannot
    type).
    """

    default: object
    description: str
    range: tuple | None = None
    choices: tuple | None = None
    live: bool = False
    doc: str = ''
    example: object = field(default=_UNSET, compare=False)
    commented: bool = False

    @property
    def shown(self):
        """The value ``config/<node>.yaml`` shows."""
        return self.default if self.example is _UNSET else self.example


@dataclass(frozen=True)
class NodeTable:
    """The parameters of one node (``params``, in the order its config file shows them),
    the comment at the top of that file (``header``) and anything the file holds after the
    parameters (``tail``, verbatim: e.g. a nested block read by a core module). ``file`` is
    the file's name under ``config/`` (default ``<node>.yaml``)."""

    node: str
    header: str
    params: dict
    tail: str = ''
    file: str = ''

    @property
    def config_file(self) -> str:
        """The file under ``config/`` this table renders."""
        return self.file or f'{self.node}.yaml'

    def __post_init__(self):
        for name, spec in self.params.items():
            if not isinstance(spec, Param):
                raise TypeError(f'{self.node}.{name}: declare it with a Param')


def table(node: str) -> NodeTable:
    """The table of ``node`` (one of :data:`NODES`)."""
    return importlib.import_module(f'herd_ros.params.{node}').TABLE


def _kind(default) -> str:
    if isinstance(default, bool):
        return 'bool'
    if isinstance(default, int):
        return 'integer'
    if isinstance(default, float):
        return 'number'
    if isinstance(default, str):
        return 'string'
    return 'list'


def problem(spec: Param, value) -> str | None:
    """Why ``value`` does not fit ``spec``'s type, range and choices ("must be ..."), or
    None. A float parameter takes any finite int or float; NaN and inf never pass."""
    kind = _kind(spec.default)
    if kind == 'bool':
        ok = isinstance(value, bool)
    elif kind == 'integer':
        ok = isinstance(value, int) and not isinstance(value, bool)
    elif kind == 'number':
        ok = (isinstance(value, (int, float)) and not isinstance(value, bool)
              and math.isfinite(value))
    elif kind == 'string':
        ok = isinstance(value, str)
    else:
        ok = isinstance(value, (list, tuple)) or type(value).__name__ == 'array'
    if not ok:
        article = 'an' if kind[0] in 'aeiou' else 'a'
        finite = ' finite' if kind == 'number' else ''
        return f'must be{finite} {article} {kind}, got {value!r}'
    if spec.choices is not None and value not in spec.choices:
        return f'must be one of {", ".join(str(c) for c in spec.choices)}, got {value!r}'
    if spec.range is not None and kind in ('integer', 'number'):
        lo, hi = spec.range
        if not lo <= value <= hi:
            return f'must be within [{lo:g}, {hi:g}], got {value!r}'
    return None


def yaml_value(value) -> str:
    """``value`` as a YAML flow scalar or list that reads back as the same type (a float
    always with a '.' so YAML 1.1 readers, PyYAML and rcl's parser, keep it a float)."""
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        text = repr(value)
        if 'e' in text and '.' not in text.split('e')[0]:
            mantissa, exponent = text.split('e')
            text = f'{mantissa}.0e{exponent}'
        return text
    if isinstance(value, str):
        plain = (value and value.strip() == value and (value[0].isalpha() or value[0] == '/')
                 and all(c.isalnum() or c in '_-./' for c in value)
                 and value.lower() not in ('true', 'false', 'yes', 'no', 'on', 'off',
                                           'null', 'none'))
        return value if plain else "'" + value.replace("'", "''") + "'"
    return '[' + ', '.join(yaml_value(v) for v in value) + ']'


def render_yaml(t: NodeTable) -> str:
    """``config/<node>.yaml`` of table ``t``: header, then every parameter with its doc."""
    lines = [t.header.rstrip('\n'), f'{t.node}:', '  ros__parameters:']
    for name, spec in t.params.items():
        for line in spec.doc.split('\n') if spec.doc else ():
            lines.append(f'    # {line}'.rstrip() if line else '')
        entry = f'{name}: {yaml_value(spec.shown)}'
        lines.append(f'    # {entry}' if spec.commented else f'    {entry}')
    text = '\n'.join(lines) + '\n'
    return text + t.tail


def markdown_table(t: NodeTable) -> str:
    """The parameters of ``t`` as a Markdown table (name, default, range or choices, live,
    description)."""
    rows = ['| parameter | default | range / choices | live | description |',
            '|---|---|---|---|---|']
    for name, spec in t.params.items():
        limits = (', '.join(str(c) for c in spec.choices) if spec.choices else
                  f'[{spec.range[0]:g}, {spec.range[1]:g}]' if spec.range else '')
        rows.append(f'| `{name}` | `{yaml_value(spec.default)}` | {limits} | '
                    f'{"yes" if spec.live else ""} | {spec.description} |')
    return '\n'.join(rows) + '\n'


def distinct_ids(values: dict, name: str, what: str = 'ids') -> list[str]:
    """Parameter ``name`` as a non-empty list of distinct ids that are valid ROS names
    (:func:`~herd_ros.model.model_file.check_agent_id`), or :class:`ParameterError`."""
    from herd_ros.errors import HerdInputError
    from herd_ros.model.model_file import check_agent_id
    try:
        ids = [check_agent_id(a) for a in values[name]]
    except HerdInputError as exc:
        raise ParameterError(f'{name}: {exc}') from None
    if not ids or len(set(ids)) != len(ids):
        raise ParameterError(f'{name} must be a non-empty list of distinct {what}, got '
                             f'{list(values[name])!r}')
    return ids


def topic_problem(topic: str) -> str | None:
    """Why ``topic`` is not a ROS topic name (absolute or relative), or None: tokens of
    letters, digits and underscores, none starting with a digit, separated by single '/',
    optionally after a leading '~/' (the rules of rcl's topic name validation)."""
    body = topic[2:] if topic.startswith('~/') else topic.lstrip('/')
    if topic.startswith('//') or not body:
        return 'must not be empty or start with //'
    for token in body.split('/'):
        if not token:
            return 'must not contain // or end with /'
        if token[0].isdigit():
            return f'token {token!r} must not start with a digit'
        if not all(c.isascii() and (c.isalnum() or c == '_') for c in token):
            return f'token {token!r} holds a character other than letters, digits and _'
    return None
