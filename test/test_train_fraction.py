"""The held-out split of ``herd-ros fit``: every animal must have held-out data, checked
against hand-counted positions of staggered collar spans."""
import numpy as np
import pytest

from herd_ros.errors import HerdInputError
from herd_ros.estimation.herd_fit import (choose_train_fraction, held_out_positions,
                                          split_runs)
from herd_ros.trajectory import HerdTrajectory


def staggered(last_of_c=60, steps=100):
    """Agents a and b over all ``steps`` steps; c's collar ends after ``last_of_c``."""
    p = np.random.default_rng(0).normal(size=(steps, 3, 2))
    p[last_of_c:, 2] = np.nan
    return [HerdTrajectory(np.arange(steps) * 5.0, ['a', 'b', 'c'], p)]


def test_auto_moves_the_split_so_that_every_animal_holds_out_its_share():
    runs = staggered()
    # at 0.8 the split is step 80, after c's last position (step 59): c holds out nothing
    assert list(held_out_positions(runs, 0.8)) == [20, 20, 0]
    fraction, note = choose_train_fraction(runs, 'auto')
    # c needs 20 % of its 60 positions (12) after the split: step 48 at the latest
    assert fraction == 0.48
    assert list(held_out_positions(runs, 0.48)) == [52, 52, 12]
    assert 'c' in note and '0.48' in note and '0.8' in note
    train, test = split_runs(runs, fraction)
    assert train[0].n_steps == 48 and test[0].n_steps == 52
    assert np.isfinite(test[0].positions[:, 2]).all(-1).sum() == 12


def test_auto_keeps_the_default_when_every_animal_has_held_out_data():
    assert choose_train_fraction(staggered(last_of_c=100), 'auto') == (0.8, None)
    # c with 3 positions after the split still counts as held out
    assert choose_train_fraction(staggered(last_of_c=83), 'auto') == (0.8, None)


def test_a_given_fraction_is_kept_and_the_note_names_who_has_no_held_out_data():
    fraction, note = choose_train_fraction(staggered(), '0.8')
    assert fraction == 0.8
    assert 'c have no held-out data' in note and '--train-fraction 0.48' in note
    assert choose_train_fraction(staggered(), 1.0) == (1.0, None)      # nothing held out


def test_an_animal_seen_only_at_the_start_cannot_be_held_out():
    runs = staggered(last_of_c=2)
    fraction, note = choose_train_fraction(runs, 'auto')
    assert fraction == 0.8 and 'c have no held-out data' in note
    assert '--train-fraction' not in note


@pytest.mark.parametrize('bad', ['most', '0', '1.5', '-0.2', None])
def test_a_bad_fraction_is_one_clear_error(bad):
    with pytest.raises(HerdInputError, match='train fraction'):
        choose_train_fraction(staggered(), bad)
