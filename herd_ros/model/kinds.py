"""Every kind of herd model, and the one way to read and write them (issue 26).

A model file names its kind (``model.kind``); :data:`KINDS` maps the kind to the model's
class and its mapping codec, so every reader — the command line, the controller's
``model.*`` parameters, the estimator's model file — goes through :func:`load` /
:func:`from_dict` and every writer through :func:`save`:

* ``schwager2007``: the paper's pairwise law, :class:`~herd_ros.model.herd_model.HerdModel`
  (:mod:`herd_ros.model.model_file`);
* ``schwager2007_shared``: one distance profile shared by the herd,
  :class:`~herd_ros.model.shared_law.SharedLawModel` (:mod:`herd_ros.model.shared_law`).

Both have the same surface (``agents``, ``dt``, ``damping``, ``noise_cov``,
``next_velocity``, ``predict_one_step``, ``datum``).
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from herd_ros.errors import HerdInputError


@dataclass(frozen=True)
class Kind:
    """One model kind: its class and how its ``model:`` mapping is read and written."""

    name: str
    model_class: type
    from_dict: object          # (body, source) -> model
    to_dict: object            # model -> body


def _kinds() -> dict:
    from herd_ros.model import herd_model, model_file, shared_law
    return {k.name: k for k in (
        Kind(herd_model.KIND, herd_model.HerdModel, model_file.model_from_dict,
             model_file.model_to_dict),
        Kind(shared_law.KIND, shared_law.SharedLawModel, shared_law.shared_model_from_dict,
             shared_law.shared_model_to_dict))}


def kinds() -> dict:
    """{kind name: :class:`Kind`}."""
    return _kinds()


def kind_of(model) -> Kind:
    """The :class:`Kind` of a model object."""
    for k in _kinds().values():
        if isinstance(model, k.model_class):
            return k
    raise HerdInputError(f'{type(model).__name__} is not a herd model kind '
                         f'({", ".join(_kinds())})')


def from_dict(body: dict, source: str = 'model'):
    """The model of a ``model:`` mapping of any kind (a file's, or a node's ``model.*``
    parameters); the kind defaults to the paper's."""
    from herd_ros.model import herd_model
    name = body.get('kind', herd_model.KIND)
    known = _kinds()
    if name not in known:
        raise HerdInputError(f'{source}: model kind {name!r} is not one of '
                             f'{", ".join(repr(k) for k in known)}')
    return known[name].from_dict(body, source=source)


def load(path):
    """The model in the model file ``path``, whatever its kind; one clear error otherwise."""
    from herd_ros.model.model_file import load_model_body
    return from_dict(load_model_body(path), source=str(path))


def save(model, path, selection: dict | None = None) -> Path:
    """Write ``model`` as the model file of its kind, atomically (``selection``: the
    ``model.selection`` mapping of a selected fit,
    :func:`~herd_ros.model.model_file.selection_entry`)."""
    from herd_ros.model.model_file import dump_parameters, write_atomic
    body = kind_of(model).to_dict(model)
    if selection:
        body['selection'] = selection
    return write_atomic(path, dump_parameters(body))
