"""What a reader of the estimator's bare parameter matrix needs to know (issue 26): the
structure of its model, published with it (latched, ``/herd/model/structure``, a JSON
std_msgs/String) so that no node declares the estimator's structure a second time.

``/herd/model/params`` carries θ as a matrix agent × parameter; its rows are read with the
agents (their order), the clock step, the law, the field grid (every centre of ``field_grid``
over ``field_bounds``), for the shared law the radius and size of the distance profile,
and, when the law has a velocity alignment (:mod:`herd_ros.model.alignment`), its kernel:
``alignment_size`` bumps (0 = none; their weights are the last columns) over
``alignment_radius``, its neighbourhood and, for 'nearest', k.
"""
from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import asdict, dataclass

from herd_ros.errors import HerdInputError

LAWS = ('pairwise', 'shared')


@dataclass(frozen=True)
class ModelStructure:
    """The structure of the estimator's model (see the module docstring)."""

    agents: tuple
    dt: float
    law: str
    field_grid: tuple
    field_bounds: tuple
    interaction_radius: float
    profile_size: int
    alignment_size: int = 0
    alignment_radius: float = 0.0
    alignment_neighbourhood: str = 'radius'
    alignment_nearest: int = 7

    def __post_init__(self):
        from herd_ros.model.model_file import check_agent_id
        agents = tuple(check_agent_id(a) for a in self.agents)
        if len(agents) < 1 or len(set(agents)) != len(agents):
            raise HerdInputError(f'model structure: agents must be distinct, got {agents}')
        if self.law not in LAWS:
            raise HerdInputError(f'model structure: law must be one of {", ".join(LAWS)}, '
                                 f'got {self.law!r}')
        if self.law == 'pairwise' and len(agents) < 2:
            raise HerdInputError('model structure: the pairwise law needs two agents')
        grid, bounds = tuple(int(g) for g in self.field_grid), tuple(
            float(b) for b in self.field_bounds)
        if len(grid) != 2 or min(grid) < 1 or len(bounds) != 4 or not (
                bounds[0] < bounds[1] and bounds[2] < bounds[3]):
            raise HerdInputError(f'model structure: field_grid [nx, ny] ≥ 1 and field_bounds '
                                 f'[xmin, xmax, ymin, ymax] needed, got {grid}, {bounds}')
        numbers = (self.dt, self.interaction_radius)
        if not all(isinstance(v, (int, float)) and math.isfinite(v) and v > 0 for v in numbers):
            raise HerdInputError(f'model structure: dt and interaction_radius must be positive, '
                                 f'got {numbers}')
        if int(self.profile_size) < 1:
            raise HerdInputError('model structure: profile_size must be ≥ 1')
        object.__setattr__(self, 'agents', agents)
        object.__setattr__(self, 'field_grid', grid)
        object.__setattr__(self, 'field_bounds', bounds)
        object.__setattr__(self, 'dt', float(self.dt))
        object.__setattr__(self, 'interaction_radius', float(self.interaction_radius))
        object.__setattr__(self, 'profile_size', int(self.profile_size))
        if int(self.alignment_size) < 0 or (int(self.alignment_size) > 0 and not (
                isinstance(self.alignment_radius, (int, float))
                and math.isfinite(self.alignment_radius) and self.alignment_radius > 0)):
            raise HerdInputError('model structure: alignment_size ≥ 0, and a positive '
                                 'alignment_radius with it')
        object.__setattr__(self, 'alignment_size', int(self.alignment_size))

    def alignment_kernel(self):
        """The :class:`~herd_ros.model.alignment.AlignmentKernel` of the last
        ``alignment_size`` columns, or None."""
        if not self.alignment_size:
            return None
        from herd_ros.model.alignment import AlignmentKernel
        return AlignmentKernel.even(self.alignment_radius, self.alignment_size,
                                    self.alignment_neighbourhood, self.alignment_nearest)

    @property
    def n_params(self) -> int:
        """Columns of the parameter matrix: 1 + 2(N − 1) + 2K (pairwise) or 1 + B + 2K, then
        the alignment's B_a."""
        k = self.field_grid[0] * self.field_grid[1]
        middle = 2 * (len(self.agents) - 1) if self.law == 'pairwise' else self.profile_size
        return 1 + middle + 2 * k + self.alignment_size

    def to_json(self) -> str:
        """The structure as JSON (the latched /herd/model/structure message)."""
        body = asdict(self)
        body.update(agents=list(self.agents), field_grid=list(self.field_grid),
                    field_bounds=list(self.field_bounds))
        return json.dumps(body, sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> 'ModelStructure':
        """Read a structure message; a malformed one is a :class:`HerdInputError`."""
        try:
            body = json.loads(text)
            fields = cls.__dataclass_fields__
            return cls(**{name: body[name] for name in fields
                          if name in body or fields[name].default is dataclasses.MISSING})
        except (ValueError, KeyError, TypeError) as exc:
            raise HerdInputError(f'model structure: not a structure message ({exc})') from None
