"""Both hypotheses kept after a track moves (collar_filter, *the place the track left*): a
burst within reach that the track followed does not hold it when the fixes come back — the
track returns on the first fix back, inside the gate of the place it left — nor does a
single far fix that the walk component took (nor a second one while the place left the
first time is still held), while a real move to a new place is kept, and the compiled bank
does the same fix by fix."""
import numpy as np
import pytest

from herd_ros.ingest.collar_bank import OUTCOMES, CollarBank
from herd_ros.ingest.collar_filter import CollarFilter, FilterParams
from herd_ros.ingest.pipeline import DEFAULT_ACCEL_STD, DEFAULT_VELOCITY_TAU

pytestmark = pytest.mark.usefixtures('kernels')

HOME = 30           # grazing fixes, one a minute
PLACE = np.array([330.0, 0.0])


def params():
    """The ingest's default model, the range rule off: the burst's place is inside the
    range (a paddock the herd crosses), so only reachability tells a burst from a move."""
    return FilterParams(accel_std=DEFAULT_ACCEL_STD, velocity_tau=DEFAULT_VELOCITY_TAU,
                        range_sigmas=0.0)


def away_and_back(k_away=3, k_back=6, seed=0):
    """Grazing about the origin (σ 5 m, a fix a minute), a silence of 5 min (330 m is then
    within reach: 3·60 + 1·240 m), ``k_away`` fixes 330 m off a minute apart, then
    ``k_back`` fixes home again a minute apart (330 m in a minute is beyond reach)."""
    rng = np.random.default_rng(seed)
    t = 60.0 * np.arange(HOME)
    t = np.r_[t, t[-1] + 300.0 + 60.0 * np.arange(k_away)]
    t = np.r_[t, t[-1] + 60.0 * np.arange(1, k_back + 1)]
    z = rng.normal(0.0, 5.0, (len(t), 2))
    z[HOME:HOME + k_away] += PLACE
    return t, z


def run(t, z):
    f = CollarFilter(params())
    return f, [f.update(s, e, n) for s, (e, n) in zip(t, z)]


def test_the_track_comes_back_from_a_burst_it_followed():
    t, z = away_and_back()
    f, out = run(t, z)
    reasons = [r.reason for r in out]
    assert reasons[HOME:HOME + 3] == ['gate', 'reinitialised', 'accepted']   # followed
    back = HOME + 3
    # the first fix back is beyond reach of the track (at the burst) and inside the gate of
    # the place it left (grazing there, 5 m fixes): the track is back at once
    assert reasons[back] == 'reinitialised'
    assert all(r.accepted for r in out[back:])
    assert np.hypot(*f.x[:2]) < 20.0
    assert f.left_place is None             # the burst's place is not kept


def test_a_fix_back_outside_the_gate_of_the_place_left_needs_a_second():
    """A grazing collar's model (σ_a 0.005 m/s²: about 14 m of drift in the 9 minutes
    since the track left its place) and fixes back 100 m from that place: within reach
    of it, not inside its gate. A reachable chain, confirmed on the second fix back."""
    from dataclasses import replace
    t, z = away_and_back()
    z[HOME + 3:] += [0.0, 100.0]
    f = CollarFilter(replace(params(), accel_std=0.005))
    out = [f.update(s, e, n) for s, (e, n) in zip(t, z)]
    assert [r.reason for r in out[HOME:HOME + 3]] == ['gate', 'reinitialised', 'accepted']
    back = HOME + 3
    assert [r.reason for r in out[back:back + 2]] == ['speed', 'reinitialised']
    assert all(r.accepted for r in out[back + 1:])
    assert np.hypot(*(f.x[:2] - [0.0, 100.0])) < 20.0


def single_far_fix(seed=0):
    """Grazing about the origin (σ 5 m, a fix a minute), a silence of 4 min, one fix 150 m
    off (a walk could get there: the walk component takes it), then home again, a fix a
    minute (150 m in a minute: beyond reach of the far fix)."""
    rng = np.random.default_rng(seed)
    t = np.r_[60.0 * np.arange(HOME), 60.0 * (HOME - 1) + 240.0 + 60.0 * np.arange(6)]
    z = rng.normal(0.0, 5.0, (len(t), 2))
    z[HOME] += [150.0, 0.0]
    return t, z


def walk_params():
    """A fitted grazing collar's filter: its own model σ_a 0.005 m/s² beside the walk
    component of the ingest (pipeline.with_walk: σ_a 0.1 m/s², 5 m added to the fixes)."""
    from dataclasses import replace
    return replace(params(), accel_std=0.005, walk_accel_std=0.1,
                   walk_velocity_tau=DEFAULT_VELOCITY_TAU, walk_position_std=5.0)


def test_a_far_fix_the_walk_took_does_not_hold_the_track():
    t, z = single_far_fix()
    f = CollarFilter(walk_params())
    out = [f.update(s, e, n) for s, (e, n) in zip(t, z)]
    assert out[HOME].reason == 'accepted'                    # the walk component took it
    # the next fix, home again, is beyond reach of the track and inside the gate of the
    # place the track left: back at once, and the rest accepted
    assert out[HOME + 1].reason == 'reinitialised'
    assert all(r.accepted for r in out[HOME + 1:])
    assert np.hypot(*f.x[:2]) < 20.0


def second_far_fix(seed=0, stay=4, k_back=4):
    """:func:`single_far_fix`'s walk, but the animal stays at the far place C (150 m off,
    ``stay`` fixes a minute apart: the track follows it, the place it left still held),
    then, after 280 s of silence, one fix 400 m from C (within reach: the walk takes it),
    then ``k_back`` fixes at C again a minute apart (400 m in a minute: beyond reach)."""
    rng = np.random.default_rng(seed)
    t = np.r_[60.0 * np.arange(HOME), 60.0 * (HOME - 1) + 240.0 + 60.0 * np.arange(1 + stay)]
    t = np.r_[t, t[-1] + 280.0, t[-1] + 280.0 + 60.0 * np.arange(1, k_back + 1)]
    z = rng.normal(0.0, 5.0, (len(t), 2))
    z[HOME:] += [150.0, 0.0]
    z[HOME + 1 + stay] += [0.0, 400.0]
    return t, z


def test_a_second_far_fix_while_a_place_is_held_does_not_hold_the_track():
    """Real cattle loggers leave for a fix again before the place left the first time is
    forgotten (doc/gps_ingest.md): both places are kept, and the fixes back at the
    second go back to it at once (with the first place alone they were a jump: refused
    until the collar went stale)."""
    t, z = second_far_fix()
    f = CollarFilter(walk_params())
    out = [f.update(s, e, n) for s, (e, n) in zip(t, z)]
    far = HOME + 5
    assert out[HOME].reason == 'accepted' and out[far].reason == 'accepted'  # the walk's
    assert out[far + 1].reason == 'reinitialised'            # back at C at once
    assert all(r.accepted for r in out[far + 1:])
    assert np.hypot(*(f.x[:2] - [150.0, 0.0])) < 20.0
    assert f.left_place is None and f.left_recent is None


def test_without_a_place_left_the_fixes_back_are_a_jump():
    """The same fixes when the track reached the burst place by walking there (accepted
    fix by fix, no chain adopted): nothing is kept, and the way back is a jump."""
    t, z = away_and_back()
    f = CollarFilter(params())
    for s, (e, n) in zip(t[:HOME + 3], z[:HOME + 3]):
        f.update(s, e, n)
    f.left_place = None
    out = [f.update(s, e, n) for s, (e, n) in zip(t[HOME + 3:], z[HOME + 3:])]
    assert [r.reason for r in out] == ['speed'] * 6


def test_a_real_move_is_kept_and_the_place_left_forgotten():
    t, z = away_and_back(k_away=3 + FilterParams().reacquire_fixes + 5, k_back=0)
    f, out = run(t, z)
    assert out[HOME + 1].reason == 'reinitialised'
    assert all(r.accepted for r in out[HOME + 1:])
    assert f.left_place is None                     # the new place held
    assert np.hypot(*(f.x[:2] - PLACE)) < 20.0


@pytest.mark.parametrize('walk', [False, True])
def test_the_bank_does_the_same_fix_by_fix(walk):
    cases = [away_and_back(), away_and_back(k_away=4, k_back=3, seed=1),
             away_and_back(k_away=20, k_back=0, seed=2), single_far_fix(3),
             second_far_fix(4), second_far_fix(5, stay=2, k_back=1)]
    p = walk_params() if walk else params()
    bank = CollarBank(len(cases), p)
    for i, (t, z) in enumerate(cases):
        m = len(t)
        R = bank.measurement_covariances(np.zeros(m, np.int64), np.zeros((m, 9)))
        batch = bank.process(np.full(m, i), t, z[:, 0], z[:, 1], np.zeros(m, np.int64), R)
        f = CollarFilter(p)
        ref = [f.update(s, e, n) for s, (e, n) in zip(t, z)]
        assert [OUTCOMES[c] for c in batch.outcome] == [r.reason for r in ref]
        assert np.allclose(bank.x[i], f.x, atol=1e-9)
        assert np.isnan(bank.left_place[i, 0]) == (f.left_place is None)
        assert np.isnan(bank.left_place[i, 8]) == (f.left_recent is None)
