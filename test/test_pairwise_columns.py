"""The one builder of the pairwise law's interaction columns (issue 26), by hand: the batch
fit, the selection and the RLS all read it."""
import numpy as np
import pytest

from herd_ros.errors import HerdInputError
from herd_ros.model.regressors import interaction_columns, pairwise_columns


def test_columns_by_hand():
    p = np.array([[[0.0, 0.0], [3.0, 4.0], [0.0, 2.0]]])
    e, eod, same = pairwise_columns(p, [0, 1, 2])
    assert e.shape == (1, 3, 2, 2) and not same.any()
    assert e[0, 0] == pytest.approx(np.array([[0.6, 0.8], [0.0, 1.0]]))  # 0 to 1, 0 to 2
    assert eod[0, 0] == pytest.approx(np.array([[0.12, 0.16], [0.0, 0.5]]))
    r13 = np.sqrt(13.0)                                              # agent 2 to 0, to 1
    assert e[0, 2] == pytest.approx(np.array([[0.0, -1.0], [3 / r13, 2 / r13]]))
    # the batch view of one agent over time is the same builder's
    e0, eod0 = interaction_columns(p, 0)
    assert np.array_equal(e0, e[:, 0]) and np.array_equal(eod0, eod[:, 0])


def test_missing_neighbour_drops_out_and_coincident_agents_are_flagged():
    p = np.array([[[0.0, 0.0], [np.nan, np.nan], [1.0, 0.0]],
                  [[0.0, 0.0], [0.0, 0.0], [1.0, 0.0]]])
    e, eod, same = pairwise_columns(p, [0])
    assert (e[0, 0, 0] == 0).all() and e[0, 0, 1] == pytest.approx([1.0, 0.0])
    assert same.tolist() == [[False], [True]]
    with pytest.raises(HerdInputError, match='same position at step 1'):
        interaction_columns(p, 0)
