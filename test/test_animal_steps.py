"""The model steps each animal has been in the herd (controller warm-up per animal)."""
import numpy as np

from herd_ros.control.animal_steps import AnimalSteps


def test_each_model_step_with_a_pose_counts_once():
    steps = AnimalSteps(3, dt=120.0)
    nan = np.nan
    # a herd clock of 30 s: four ticks per model step; b starts late, c never reports
    for k in range(12):                                   # ticks 0 ... 330 s: steps 0, 1, 2
        t = 30.0 * k
        b = (1.0, 1.0) if t >= 200.0 else (nan, nan)      # b from 210 s: steps 1 and 2
        steps.observe(t, np.array([(0.0, 0.0), b, (nan, nan)]))
    assert steps.count.tolist() == [3, 2, 0]
    assert steps.ready(2).tolist() == [True, True, False]
    assert steps.ready(3).tolist() == [True, False, False]
    assert steps.ready(0).all()
    steps.observe(330.0, np.array([(0.0, 0.0), (1.0, 1.0), (nan, 1.0)]))  # same step again;
    assert steps.count.tolist() == [3, 2, 0]              # half a position is no pose
