"""The model file of doc/formats.md: a ROS 2 parameters YAML (usable with ``--params-file``).

::

    /**:
      ros__parameters:
        model:
          kind: schwager2007
          dt: 60.0
          frame_id: map
          datum: [lat, lon, alt]
          velocity_memory: 1.0      # optional (absent = 1, the paper's model)
          agents: [cow_1, cow_2]
          cow_1: {damping, neighbors, theta1, theta2, rbf_centers_x, rbf_centers_y,
                  rbf_sigma, field_u, field_v, noise_cov, theta_se}

Every number is written as a float (ROS parameter arrays must be homogeneous), and agent
ids must be valid ROS name tokens because they become parameter and topic names.
"""
from __future__ import annotations

import os
import tempfile
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import yaml

from herd_ros.agent_ids import ROS_TOKEN
from herd_ros.errors import HerdInputError
from herd_ros.model.herd_model import KIND, AgentLaw, HerdModel
from herd_ros.model.rbf_field import RbfBasis
from herd_ros.model.noise_regimes import check_regimes
from herd_ros.model.velocity_memory import check_memories

AGENT_KEYS = ('damping', 'neighbors', 'theta1', 'theta2', 'rbf_centers_x', 'rbf_centers_y',
              'rbf_sigma', 'field_u', 'field_v', 'noise_cov')


class _FlowListDumper(getattr(yaml, 'CSafeDumper', yaml.SafeDumper)):
    """Block mappings, flow (inline) sequences: the layout of doc/formats.md (libyaml's emitter
    where PyYAML has it: a fine field's file is 10× faster to write)."""


def _represent_list(dumper, data):
    return dumper.represent_sequence('tag:yaml.org,2002:seq', data, flow_style=True)


_FlowListDumper.add_representer(list, _represent_list)
# libyaml's safe loader where PyYAML has it (a fine field's file: 0.3 s instead of 3 s)
_LOADER = getattr(yaml, 'CSafeLoader', yaml.SafeLoader)


def check_agent_id(agent: str) -> str:
    """``agent`` if it is a valid ROS name part (letters, digits, underscores, starting with a
    letter); one clear error otherwise."""
    if not ROS_TOKEN.match(str(agent)):
        raise HerdInputError(f'agent id {agent!r} is not a valid ROS name (letters, digits and '
                             f'underscores, starting with a letter): it becomes a topic and '
                             f'parameter name')
    return str(agent)


def float_list(values) -> list[float]:
    """Numbers as a list of Python floats (ROS parameter arrays must be homogeneous)."""
    return [float(v) for v in np.asarray(values, dtype=float).ravel()]


def model_to_dict(model: HerdModel) -> dict:
    """The ``model:`` mapping of the parameters file."""
    body = {'kind': KIND, 'dt': float(model.dt), 'frame_id': model.frame_id}
    if model.datum is not None:
        body['datum'] = float_list(model.datum)
    body['agents'] = [check_agent_id(a) for a in model.agents]
    for a in model.agents:
        law = model.laws[a]
        if law.basis.size == 0:
            raise HerdInputError(f'agent {a} has no field centre; a ROS parameter array cannot '
                                 f'be empty (lower --min-visits or widen --bounds)')
        if len(law.neighbors) == 0:
            raise HerdInputError(f'agent {a} has no neighbour; the pairwise law needs at least '
                                 f'two agents')
        entry = {
            'damping': float(law.damping),
            'neighbors': [check_agent_id(j) for j in law.neighbors],
            'theta1': float_list(law.theta1),
            'theta2': float_list(law.theta2),
            'rbf_centers_x': float_list(law.basis.centers[:, 0]),
            'rbf_centers_y': float_list(law.basis.centers[:, 1]),
            'rbf_sigma': float_list(law.basis.sigma),
            'field_u': float_list(law.field_u),
            'field_v': float_list(law.field_v),
            'noise_cov': float_list(law.noise_cov),
        }
        if law.theta_se is not None:
            entry['theta_se'] = float_list(law.theta_se)
        body[a] = entry
    add_model_meta(body, model)
    return body


def _number_lists(first, second, keys: str, where: str) -> tuple[np.ndarray, np.ndarray]:
    """Two model-file lists as flat float arrays, or one clear error naming ``keys``."""
    try:
        return (np.asarray(first, dtype=float).ravel(), np.asarray(second, dtype=float).ravel())
    except (TypeError, ValueError):
        raise HerdInputError(f'{where}.{keys} must be lists of numbers') from None


def read_regimes(cov, trans, n_agents: int, where: str):
    """(covariances (N, K, 2, 2), transition (N, K, K)) from the flat model-file arrays."""
    c, t = _number_lists(cov, trans, 'noise_regime_cov/noise_regime_transition', where)
    k = len(c) // (4 * max(n_agents, 1))
    if k < 1 or len(c) != 4 * k * n_agents or len(t) != k * k * n_agents:
        raise HerdInputError(f'{where}: noise_regime_cov needs N × K × 4 numbers and '
                             f'noise_regime_transition N × K × K ({n_agents} agents)')
    pairs = [check_regimes(c.reshape(n_agents, k, 4)[i], t.reshape(n_agents, k, k)[i],
                           f'{where}, agent {i}') for i in range(n_agents)]
    return np.stack([p[0] for p in pairs]), np.stack([p[1] for p in pairs])


def read_home(center, gain, n_agents: int, where: str):
    """(μ (N, 2), K (N, 2, 2)) of the space-use home pull from the flat model-file arrays."""
    c, k = _number_lists(center, gain, 'space_use_home_center/space_use_home_gain', where)
    if len(c) != 2 * n_agents or len(k) != 4 * n_agents:
        raise HerdInputError(f'{where}: space_use_home_center needs N × 2 numbers and '
                             f'space_use_home_gain N × 4 ({n_agents} agents)')
    if not (np.isfinite(c).all() and np.isfinite(k).all()):
        raise HerdInputError(f'{where}: space_use_home_center/space_use_home_gain must be '
                             f'finite')
    return c.reshape(n_agents, 2), k.reshape(n_agents, 2, 2)


def read_home_range(values, n_agents: int, where: str, key: str = 'space_use_home_range'):
    """Σ (N, 2, 2) of a range key (``space_use_home_range``, ``herd_place_range``): each
    agent's range covariance (finite, symmetric, positive semi-definite)."""
    try:
        r = np.asarray(values, dtype=float).ravel()
    except (TypeError, ValueError):
        raise HerdInputError(f'{where}.{key} must be a list of numbers') from None
    if len(r) != 4 * n_agents or not np.isfinite(r).all():
        raise HerdInputError(f'{where}: {key} needs N × 4 finite numbers ({n_agents} agents)')
    cov = r.reshape(n_agents, 2, 2)
    if not (np.allclose(cov, np.swapaxes(cov, 1, 2)) and
            (np.linalg.eigvalsh(cov) >= -1e-9 * np.abs(cov).max(initial=1.0)).all()):
        raise HerdInputError(f'{where}: {key} must hold symmetric positive semi-definite '
                             f'2 × 2 covariances')
    return cov


#: The model-file keys of ``meta['herd_place']`` (:mod:`herd_ros.model.herd_place`).
HERD_PLACE_KEYS = ('herd_place_offset', 'herd_place_gain', 'herd_place_range')
#: The optional cap of each place pull ((P2) of :mod:`herd_ros.model.herd_place`).
HERD_PLACE_CAP = 'herd_place_cap'


def read_herd_place(body: dict, given: list, n_agents: int, where: str):
    """(m (N, 2), K (N, 2, 2), S (N, 2, 2)) of the herd place from its three keys (all or
    none), and the caps c (N,) when ``herd_place_cap`` is given, checked."""
    if len(given) != len(HERD_PLACE_KEYS):
        raise HerdInputError(f'{where}.{"/".join(HERD_PLACE_KEYS)} go together')
    m, k = _number_lists(body['herd_place_offset'], body['herd_place_gain'],
                         'herd_place_offset/herd_place_gain', where)
    if len(m) != 2 * n_agents or len(k) != 4 * n_agents or not (
            np.isfinite(m).all() and np.isfinite(k).all()):
        raise HerdInputError(f'{where}: herd_place_offset needs N × 2 finite numbers and '
                             f'herd_place_gain N × 4 ({n_agents} agents)')
    s = read_home_range(body['herd_place_range'], n_agents, where, 'herd_place_range')
    place = (m.reshape(n_agents, 2), k.reshape(n_agents, 2, 2), s)
    if HERD_PLACE_CAP not in body:
        return place
    try:
        cap = np.asarray(body[HERD_PLACE_CAP], dtype=float).ravel()
    except (TypeError, ValueError):
        raise HerdInputError(f'{where}.{HERD_PLACE_CAP} must be a list of numbers') from None
    if len(cap) != n_agents or not (np.isfinite(cap).all() and (cap >= 0).all()):
        raise HerdInputError(f'{where}: {HERD_PLACE_CAP} needs N finite numbers ≥ 0 '
                             f'({n_agents} agents)')
    return place + (cap,)


#: Per-agent positive factors kept in ``meta`` and the model file under the same key.
PER_AGENT_FACTORS = ('prediction_scale', 'noise_scale')

#: Model-level meta entries stored as two flat lists: (meta key, file keys, reader).
PAIRED_META = (
    ('noise_regimes', ('noise_regime_cov', 'noise_regime_transition'), read_regimes),
    ('space_use_home', ('space_use_home_center', 'space_use_home_gain'), read_home))


def add_model_meta(body: dict, model) -> None:
    """The model-wide keys kept in ``model.meta``:

    * ``prediction_scale`` (one per agent, agents order): the factor on Δt²Q_i that makes
      the 90 % prediction ellipse of
      :func:`~herd_ros.simulation.prediction.prediction_covariance` hold 90 % of the
      training residuals (written by ``herd-ros fit``; 1 if absent);
    * ``noise_scale`` (one per agent): the factor on the noise std of every free
      simulation of the law (robots, ``simulate``) that keeps each animal's pace
      (:mod:`herd_ros.simulation.pace_calibration`; written by ``herd-ros fit``; 1 if
      absent);
    * ``velocity_memory`` κ (:mod:`herd_ros.model.velocity_memory`): one number for the
      herd or one per agent (agents order); written when some κ < 1, absent = 1, the
      paper's model;
    * ``noise_regime_cov`` [N × K × (qxx, qxy, qyx, qyy)] and ``noise_regime_transition``
      [N × K × K] (agents order, row-major): the stop-and-go noise of
      :mod:`herd_ros.model.noise_regimes`; absent = Gaussian noise N(0, Q_i);
    * ``space_use_home_center`` [N × (x, y)] and ``space_use_home_gain`` [N × (kxx, kxy,
      kyx, kyy)]: the home pull −K_i (p − μ_i) of the space-use field, (S2) of
      :mod:`herd_ros.model.space_use_field`, added to the RBF field; absent = none;
      with ``space_use_home_range`` [N × (σxx, σxy, σyx, σyy)], each agent's range
      covariance, the pull acts only beyond the range's edge
      (:func:`~herd_ros.model.space_use_field.home_drift`; the ``estimator``'s models);
    * ``herd_place_offset`` [N × (x, y)], ``herd_place_gain`` [N × 4] and
      ``herd_place_range`` [N × 4]: each agent's place in the herd, the mean m_i and
      covariance S_i of its offset from the others' centroid and the gain K_i of the pull
      at that range's edge ((P1) of :mod:`herd_ros.model.herd_place`); absent = none;
      ``herd_place_cap`` [N]: the most each pull may be (m/s per step, (P2)); absent = no
      cap (the ``estimator``'s models).
    """
    meta = model.meta or {}
    for name, keys, _ in PAIRED_META:
        if meta.get(name) is not None:
            for key, values in zip(keys, meta[name]):
                body[key] = float_list(np.asarray(values).ravel())
    home = meta.get('space_use_home')
    if home is not None and len(home) > 2:
        body['space_use_home_range'] = float_list(np.asarray(home[2]).ravel())
    if meta.get('herd_place') is not None:
        for key, values in zip(HERD_PLACE_KEYS + (HERD_PLACE_CAP,), meta['herd_place']):
            body[key] = float_list(np.asarray(values).ravel())
    for key in PER_AGENT_FACTORS:
        if meta.get(key) is not None:
            body[key] = float_list(meta[key])
    memory = check_memories(meta.get('velocity_memory', 1.0), len(model.agents))
    if (memory != 1.0).any():
        same = (memory == memory[0]).all()
        body['velocity_memory'] = float(memory[0]) if same else float_list(memory)
    if getattr(model, 'alignment', None) is not None:
        body['alignment'] = model.alignment.to_dict(model.agents)


def read_alignment(body: dict, agents, source: str):
    """The model's alignment term (:mod:`herd_ros.model.alignment`) from its
    ``alignment`` mapping, or None when the file has none."""
    if 'alignment' not in body:
        return None
    from herd_ros.model.alignment import VelocityAlignment
    return VelocityAlignment.from_dict(body['alignment'], agents, f'{source}: model')


def read_model_meta(body: dict, n_agents: int, source: str) -> dict:
    """The ``meta`` entries for :func:`add_model_meta`'s keys, checked."""
    meta = {}
    for name, (first, second), read in PAIRED_META:
        if (first in body) != (second in body):
            raise HerdInputError(f'{source}: model.{first} and model.{second} go together')
        if first in body:
            meta[name] = read(body[first], body[second], n_agents, f'{source}: model')
    given = [k for k in HERD_PLACE_KEYS if k in body]
    if HERD_PLACE_CAP in body and not given:
        raise HerdInputError(f'{source}: model.{HERD_PLACE_CAP} needs '
                             f'{"/".join(HERD_PLACE_KEYS)}')
    if given:
        meta['herd_place'] = read_herd_place(body, given, n_agents, f'{source}: model')
    if 'space_use_home_range' in body:
        if 'space_use_home' not in meta:
            raise HerdInputError(f'{source}: model.space_use_home_range needs '
                                 f'space_use_home_center and space_use_home_gain')
        meta['space_use_home'] += (read_home_range(body['space_use_home_range'], n_agents,
                                                   f'{source}: model'),)
    if 'velocity_memory' in body:
        try:
            meta['velocity_memory'] = check_memories(body['velocity_memory'], n_agents)
        except HerdInputError as err:
            raise HerdInputError(f'{source}: model.{err}') from None
    for key in PER_AGENT_FACTORS:
        if key not in body:
            continue
        try:
            scale = np.asarray(body[key], dtype=float).ravel()
        except (TypeError, ValueError):
            raise HerdInputError(f'{source}: model.{key} is not a list of numbers') from None
        if len(scale) != n_agents or not (np.isfinite(scale).all() and (scale > 0).all()):
            raise HerdInputError(f'{source}: model.{key} needs one positive number per '
                                 f'agent ({n_agents})')
        meta[key] = scale
    return meta


def model_from_dict(body: dict, source: str = 'model') -> HerdModel:
    """Inverse of :func:`model_to_dict`; errors name the source and the key."""
    def need(mapping, key, where):
        if key not in mapping:
            raise HerdInputError(f'{source}: {where} has no key {key!r}')
        return mapping[key]

    kind = body.get('kind', KIND)
    if kind != KIND:
        raise HerdInputError(f'{source}: model kind {kind!r} is not {KIND!r}')
    agents = [str(a) for a in need(body, 'agents', 'model')]
    laws = {}
    for a in agents:
        entry = need(body, a, 'model')
        for key in AGENT_KEYS:
            need(entry, key, f'model.{a}')
        try:
            cx = np.asarray(entry['rbf_centers_x'], dtype=float)
            cy = np.asarray(entry['rbf_centers_y'], dtype=float)
            if cx.shape != cy.shape:
                raise HerdInputError(f'{source}: model.{a}: rbf_centers_x and rbf_centers_y '
                                     f'differ in length')
            basis = RbfBasis(np.column_stack([cx, cy]), np.asarray(entry['rbf_sigma'], float))
            laws[a] = AgentLaw(
                damping=float(entry['damping']),
                neighbors=[str(j) for j in entry['neighbors']],
                theta1=entry['theta1'], theta2=entry['theta2'], basis=basis,
                field_u=entry['field_u'], field_v=entry['field_v'],
                noise_cov=entry['noise_cov'], theta_se=entry.get('theta_se'))
        except (TypeError, ValueError) as exc:
            if isinstance(exc, HerdInputError):
                raise HerdInputError(f'{source}: model.{a}: {exc}') from None
            raise HerdInputError(f'{source}: model.{a}: malformed numbers ({exc})') from None
    return HerdModel(agents=agents, dt=float(need(body, 'dt', 'model')), laws=laws,
                     frame_id=str(body.get('frame_id', 'map')), datum=body.get('datum'),
                     meta=read_model_meta(body, len(agents), source),
                     alignment=read_alignment(body, agents, source))


def dump_parameters(model_body: dict, node: str = '/**') -> str:
    """Text of a ROS parameters YAML with ``model_body`` under ``model``."""
    return yaml.dump({node: {'ros__parameters': {'model': model_body}}},
                     Dumper=_FlowListDumper, sort_keys=False, width=100)


@contextmanager
def atomic_open(path, mode: str = 'w'):
    """Open a temporary file next to ``path``; on success it is fsynced and renamed over
    ``path`` (readers never see half a file, a crash leaves the old one), else removed."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f'.{path.name}.', suffix='.tmp')
    try:
        with os.fdopen(fd, mode) as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def write_atomic(path, text: str) -> Path:
    """Write ``text`` to ``path`` by write-then-rename (:func:`atomic_open`)."""
    with atomic_open(path, 'w') as fh:
        fh.write(text)
    return Path(path)


def save_model(model: HerdModel, path, selection: dict | None = None) -> Path:
    """Write the model file of doc/formats.md (with ``selection``: the ``model.selection``
    mapping of a selected fit, see :func:`selection_entry`); :func:`herd_ros.model.kinds
    .save`, which writes every kind."""
    from herd_ros.model.kinds import save
    return save(model, path, selection)


def selection_entry(selection: dict) -> dict:
    """The ``model.selection`` mapping of a model file — how ``herd-ros fit`` chose the
    structure (scalars and homogeneous arrays only, so the file stays a ROS parameters
    file)::

        selection:
          method: blocked cross-validation (10 blocks per run) of the one-step error, ...
          terms: damping+interactions+field   # the terms kept; left-out terms are zero
          interaction_law: pairwise           # or shared, or none
          own_profile_agents: [dog]           # shared law: agents with their own profile
                                              # (absent if none)
          grid: [4.0, 4.0]                    # field grid (absent without a field; the
                                              # model then has one centre of weight 0)
          ridge: 0.0
          velocity_memory: 0.35               # κ chosen, or one per agent (absent at 1;
                                              # the model's own velocity_memory key is
                                              # what is used)
          loss: l2                            # or robust (--loss robust)
          field: space-use                    # --field space-use (absent: fitted)
          noise_regimes: 3                    # --noise regimes: K kept by BIC (absent: 1)
          cv_rms: 0.0707                      # one-step RMS (m) of the chosen structure
          cv_rms_constant_velocity: 0.0720
          cv_rms_stay_put: 0.4224
    """
    cv = selection['cv_rms']
    out = {'method': selection['method'], 'terms': selection['terms'],
           'interaction_law': selection['interaction_law'] or 'none'}
    if selection.get('own_profile_agents'):
        out['own_profile_agents'] = [str(a) for a in selection['own_profile_agents']]
    if selection['grid']:
        out['grid'] = [float(g) for g in selection['grid']]
    memory = np.atleast_1d(np.asarray(selection.get('velocity_memory', 1.0), dtype=float))
    if (memory != 1.0).any():
        out['velocity_memory'] = float(memory[0]) if len(memory) == 1 else float_list(memory)
    out.update({'ridge': float(selection['ridge']), 'loss': selection.get('loss', 'l2')})
    if selection.get('field', 'fitted') != 'fitted':
        out['field'] = str(selection['field'])
    if int(selection.get('noise_regimes', 1)) > 1:
        out['noise_regimes'] = int(selection['noise_regimes'])
    out.update({'cv_rms': float(cv['selected']),
                'cv_rms_constant_velocity': float(cv['constant_velocity']),
                'cv_rms_stay_put': float(cv['stay_put'])})
    return out


def load_model_body(path) -> dict:
    """The ``model:`` mapping of a parameters YAML (any node key), with clear errors."""
    path = Path(path)
    if not path.is_file():
        raise HerdInputError(f'{path}: no such model file')
    try:
        doc = yaml.load(path.read_text(), Loader=_LOADER)
    except yaml.YAMLError as exc:
        raise HerdInputError(f'{path}: not valid YAML ({str(exc).splitlines()[0]})') from None
    if not isinstance(doc, dict):
        raise HerdInputError(f'{path}: expected a ROS parameters mapping')
    for node_params in doc.values():
        if isinstance(node_params, dict):
            params = node_params.get('ros__parameters', {})
            if isinstance(params, dict) and isinstance(params.get('model'), dict):
                return params['model']
    raise HerdInputError(f'{path}: no "<node>: ros__parameters: model:" mapping found')


def load_model(path) -> HerdModel:
    """Read a model file written by :func:`save_model` (or by hand)."""
    return model_from_dict(load_model_body(path), source=str(path))
