"""The imitation model file: a ROS 2 parameters YAML (issue 7), readable with --params-file.

```yaml
/**:
  ros__parameters:
    model:
      kind: imitation
      policies: [cohesion, separation2, alignment]
      gains: [1.0, 1.0, 1.0]
      gains_se: [0.01, 0.01, 0.01]
      radius: 5.0          # communication radius r, m
      v_max: 7.0           # speed limit, m/s
      dt: 0.05             # step the policy was learned at, s
      walls: [xmin, xmax, ymin, ymax]   # only when the wall policies use an enclosure
```
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from herd_ros.errors import HerdInputError
from herd_ros.imitation.boids import ImitationPolicy


def policy_to_dict(policy: ImitationPolicy) -> dict:
    """The parameters-YAML structure of a policy."""
    se = policy.gains_se if policy.gains_se is not None else np.full(len(policy.gains), np.nan)
    model = {
        'kind': 'imitation',
        'policies': list(policy.policies),
        'gains': [float(k) for k in policy.gains],
        'gains_se': [float(s) if np.isfinite(s) else -1.0 for s in se],
        'radius': float(policy.radius),
        'v_max': float(policy.v_max),
        'dt': float(policy.dt),
    }
    if policy.walls is not None:
        model['walls'] = [float(w) for w in policy.walls]
    return {'/**': {'ros__parameters': {'model': model}}}


def write_policy_file(path, policy: ImitationPolicy) -> Path:
    """Write ``policy`` as a ROS parameters YAML (unknown standard errors are written -1.0:
    ROS double arrays have no NaN-free null)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, 'w') as fh:
        yaml.safe_dump(policy_to_dict(policy), fh, sort_keys=False, default_flow_style=None)
    return path


def policy_from_dict(doc, where: str = 'policy') -> ImitationPolicy:
    """Parse the structure of :func:`policy_to_dict` (any node name instead of ``/**``)."""
    if not isinstance(doc, dict) or not doc:
        raise HerdInputError(f'{where}: not a ROS parameters YAML (expected a mapping)')
    node = next(iter(doc.values()))
    try:
        model = node['ros__parameters']['model']
    except (TypeError, KeyError):
        raise HerdInputError(f'{where}: no <node>: ros__parameters: model: section') from None
    if not isinstance(model, dict):
        raise HerdInputError(f'{where}: model must be a mapping')
    if model.get('kind') != 'imitation':
        raise HerdInputError(f'{where}: model.kind is {model.get("kind")!r}, not imitation')
    for key in ('policies', 'gains', 'radius', 'v_max', 'dt'):
        if key not in model:
            raise HerdInputError(f'{where}: model.{key} is missing')
    policies = model['policies']
    if not isinstance(policies, list):
        raise HerdInputError(f'{where}: model.policies must be a list of names')
    try:
        gains = np.asarray(model['gains'], dtype=float)
        se = model.get('gains_se')
        se = None if se is None else np.asarray(se, dtype=float)
        walls = model.get('walls')
        radius, v_max, dt = float(model['radius']), float(model['v_max']), float(model['dt'])
    except (TypeError, ValueError) as exc:
        raise HerdInputError(f'{where}: a numeric model field is not a number ({exc})') from None
    if se is not None:
        if se.shape != gains.shape:
            raise HerdInputError(f'{where}: model.gains_se must have one entry per gain')
        se = np.where(se < 0, np.nan, se)
    try:
        return ImitationPolicy(policies, gains, radius, v_max, dt, gains_se=se, walls=walls)
    except HerdInputError as exc:
        raise HerdInputError(f'{where}: model.{exc}') from None


def read_policy_file(path) -> ImitationPolicy:
    """Read a policy file written by :func:`write_policy_file` (or by hand)."""
    path = Path(path)
    if not path.is_file():
        raise HerdInputError(f'{path}: no such file')
    try:
        doc = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        raise HerdInputError(f'{path}: not valid YAML ({str(exc).splitlines()[0]})') from None
    return policy_from_dict(doc, str(path))
