"""One load and one save for every model kind (issue 26)."""
import numpy as np
import pytest

from herd_ros.errors import HerdInputError
from herd_ros.model import kinds
from herd_ros.model.herd_model import HerdModel
from herd_ros.model.shared_law import DistanceProfile, SharedLawModel
from herd_ros.synthesis.known_truth import make_truth_model


def test_every_kind_saves_and_loads_through_one_entry(tmp_path):
    pairwise = make_truth_model(3, seed=2)
    kinds.save(pairwise, tmp_path / 'p.yaml')
    back = kinds.load(tmp_path / 'p.yaml')
    assert isinstance(back, HerdModel) and back.agents == pairwise.agents
    for a in pairwise.agents:
        assert np.allclose(back.laws[a].theta, pairwise.laws[a].theta)
    assert set(kinds.kinds()) == {'schwager2007', 'schwager2007_shared'}
    assert kinds.kind_of(pairwise).name == 'schwager2007'


def test_a_shared_law_model_round_trips(tmp_path):
    from herd_ros.estimation.online_fit import OnlineHerdEstimator
    est = OnlineHerdEstimator(['a', 'b', 'c'], 2.0, 'shared', field_grid=(2, 2),
                              field_bounds=(0.0, 10.0, 0.0, 10.0), profile_size=3)
    est.rls.theta[:] = np.random.default_rng(0).normal(0, 0.01, est.rls.theta.shape)
    est.rls.theta[:, 0] = 0.9
    model = est.model('map', None)
    assert isinstance(model, SharedLawModel)
    path = kinds.save(model, tmp_path / 's.yaml', selection={'terms': 'damping'})
    back = kinds.load(path)
    assert isinstance(back, SharedLawModel) and list(back.agents) == ['a', 'b', 'c']
    assert np.allclose(back.damping, model.damping)
    assert 'selection:' in path.read_text()


def test_an_unknown_kind_is_one_clear_error(tmp_path):
    with pytest.raises(HerdInputError, match="model kind 'swirl' is not one of"):
        kinds.from_dict({'kind': 'swirl'}, source='x.yaml')
    with pytest.raises(HerdInputError, match='not a herd model kind'):
        kinds.kind_of(DistanceProfile.even(10.0, 3))
