"""The structure the estimator publishes beside its parameter matrix (issue 26): what a
reader needs to read θ, declared once."""
import pytest

from herd_ros.errors import HerdInputError
from herd_ros.estimation.online_fit import OnlineHerdEstimator
from herd_ros.model.model_structure import ModelStructure


@pytest.mark.parametrize('law', ['pairwise', 'shared'])
def test_the_structure_reads_the_estimators_matrix(law):
    est = OnlineHerdEstimator(['a', 'b', 'c'], 5.0, law, field_grid=(3, 2),
                              field_bounds=(-10.0, 10.0, 0.0, 40.0), interaction_radius=30.0,
                              profile_size=4)
    s = est.structure()
    assert s.n_params == est.regressor.n_params == est.theta.shape[1]
    # by hand: 1 + 2(N - 1) + 2K pairwise, 1 + B + 2K shared, K = 6
    assert s.n_params == (1 + 4 + 12 if law == 'pairwise' else 1 + 4 + 12)
    back = ModelStructure.from_json(s.to_json())
    assert back == s and back.agents == ('a', 'b', 'c') and back.field_grid == (3, 2)


def test_a_bad_structure_message_is_one_clear_error():
    good = ModelStructure(('a', 'b'), 1.0, 'pairwise', (2, 2), (0, 1, 0, 1), 10.0, 3)
    for text in ['not json', '{}', good.to_json().replace('"pairwise"', '"swirl"'),
                 good.to_json().replace('"dt": 1.0', '"dt": -1.0')]:
        with pytest.raises(HerdInputError, match='model structure'):
            ModelStructure.from_json(text)
    with pytest.raises(HerdInputError, match='two agents'):
        ModelStructure(('a',), 1.0, 'pairwise', (2, 2), (0, 1, 0, 1), 10.0, 3)
