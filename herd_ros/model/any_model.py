"""Read a model file of any kind the herd commands simulate and predict with.

``schwager2007`` (the paper's pairwise law, :mod:`herd_ros.model.model_file`) and
``schwager2007_shared`` (the shared interaction law, :mod:`herd_ros.model.shared_law`); both
have the same surface (``agents``, ``dt``, ``damping``, ``noise_cov``, ``next_velocity``,
``predict_one_step``, ``datum``).
"""
from __future__ import annotations

from herd_ros.errors import HerdInputError
from herd_ros.model import herd_model, shared_law
from herd_ros.model.model_file import load_model_body, model_from_dict


def load_any_model(path):
    """The model in ``path`` (pairwise or shared law), with one clear error otherwise."""
    return any_model_from_dict(load_model_body(path), source=str(path))


def any_model_from_dict(body: dict, source: str = 'model'):
    """The ``model:`` mapping of either kind (a file's, or a node's ``model.*`` parameters)."""
    kind = body.get('kind', herd_model.KIND)
    if kind == herd_model.KIND:
        return model_from_dict(body, source=source)
    if kind == shared_law.KIND:
        return shared_law.shared_model_from_dict(body, source=source)
    raise HerdInputError(f'{source}: model kind {kind!r} is neither {herd_model.KIND!r} nor '
                         f'{shared_law.KIND!r}')
