"""The herder's online refit of the herd's response (issue 27: the adaptive herder)."""
import numpy as np

from herd_ros.herding.benchmark import Setting, run_episodes
from herd_ros.herding.model_herder import LearnedResponse, ModelHerder
from herd_ros.herding.online_response import OnlineResponse, response_rows
from herd_ros.model.distance_profile import DistanceProfile

PROFILE = DistanceProfile.even(40.0, 5)
DOG = DistanceProfile.even(60.0, 6)
#: ā, the animals' profile c (B = 5), the dog's h (B' = 6)
THETA = np.array([0.8, 0.02, 0.01, 0.005, 0.0, 0.0, -0.3, -0.2, -0.1, -0.05, 0.0, 0.0])


def response(theta=THETA, reach=100.0):
    p = len(theta)
    return LearnedResponse(np.asarray(theta, float), PROFILE, DOG, reach, np.eye(p), {})


def states(rng, S=6, N=9, D=2):
    P = rng.uniform(0.0, 50.0, (S, N, 2))
    U = rng.normal(0.0, 0.5, (S, N, 2))
    dogs = rng.uniform(-10.0, 60.0, (S, D, 2))
    return P, U, dogs


def test_the_regressors_give_the_planners_law():
    """x θ (the exact bases, :func:`response_rows`) is the velocity the planner steps with
    (the bases tabulated on a 512-point grid): ā u + Σ_j F(d_ij) e_ij + Σ_k H(d_ik) e_ik,
    F and H from the same θ, every herder fled alike."""
    rng = np.random.default_rng(0)
    P, U, dogs = states(rng)
    law = response()
    x = response_rows(P, U, dogs, PROFILE, DOG)                     # (S, N, 2, p)
    by_rows = x @ THETA
    by_law = law.velocity(P, U, dogs, np.repeat(THETA[None], len(P), axis=0))
    assert np.abs(by_rows - by_law).max() < 1e-3
    # by hand for one animal: damping, one neighbour's pull, one dog's push
    i, s = 0, 0
    e = P[s] - P[s, i]
    d = np.hypot(*e.T)
    F = PROFILE.features(d[1:]) @ THETA[1:6]
    pull = (F[:, None] * e[1:] / d[1:, None]).sum(0)
    to = dogs[s] - P[s, i]
    dd = np.hypot(*to.T)
    push = ((DOG.features(dd) @ THETA[6:])[:, None] * to / dd[:, None]).sum(0)
    assert np.allclose(by_rows[s, i], 0.8 * U[s, i] + pull + push)


def test_the_dog_term_ends_where_the_data_did():
    """Beyond ``reach`` the planner's law has no dog term (the fit never saw it there)."""
    rng = np.random.default_rng(1)
    P, U, _ = states(rng, D=1)
    far = P.mean(axis=1, keepdims=True) + 200.0                    # beyond every radius
    law = response(reach=20.0)
    with_far_dog = law.velocity(P, U, far)
    near = np.full((len(P), 1, 2), [75.0, 25.0])     # 25–80 m from every animal > reach
    assert np.allclose(law.velocity(P, U, near), with_far_dog)
    assert not np.allclose(response().velocity(P, U, near), with_far_dog)


def simulate(rng, law, steps, S=4, N=9):
    """Herds stepped by ``law`` (plus noise), a dog circling each at 5–45 m: their rows."""
    P, U, dogs = states(rng, S=S, N=N, D=1)
    phase = rng.uniform(0, 2 * np.pi, S)
    for t in range(steps):
        a = phase + 0.05 * t
        dogs = P.mean(axis=1, keepdims=True) + (25.0 + 20.0 * np.sin(0.013 * t + phase))[
            :, None, None] * np.stack([np.cos(a), np.sin(a)], -1)[:, None]
        U_next = law.velocity(P, U, dogs) + rng.normal(0.0, 0.05, P.shape)
        yield response_rows(P, U, dogs, PROFILE, DOG).reshape(S, -1, len(THETA)), \
            U_next.reshape(S, -1)
        P, U = P + U_next, U_next
        P = P - 0.05 * (P - 25.0)                   # keep the herds in the profiles' range


def test_recursive_least_squares_recovers_a_known_law():
    """Herds stepped by a known θ, fed step by step from a prior at θ = 0 (with the
    information per row of other such herds, weighing half a step): each episode's
    estimate converges to θ; an episode with no data keeps the prior."""
    rng = np.random.default_rng(2)
    S, N = 4, 9
    law = response()
    seen = np.concatenate([x.reshape(-1, len(THETA)) for x, _ in simulate(rng, law, 50)])
    prior = np.zeros_like(THETA)
    online = OnlineResponse(prior, seen.T @ seen / len(seen), S + 1, 2 * N, prior_steps=0.5)
    for x, y in simulate(rng, law, 600, S, N):
        online.update(np.arange(S), x, y)
    est = online.theta[:S]
    assert np.abs(est[:, 0] - THETA[0]).max() < 0.03
    d = np.linspace(5, 40, 8)
    truth = DOG.features(d) @ THETA[6:]
    fitted = DOG.features(d) @ est[:, 6:].T
    assert np.abs(fitted - truth[:, None]).max() < 0.05
    assert np.array_equal(online.theta[S], prior)
    assert online.rows[S] == 0 and (online.rows[:S] == 600 * 2 * N).all()


def test_the_adaptive_herder_learns_the_herd_it_herds():
    """Herding animals of the other family (the herd law with a driver profile, flight
    H(d) ≈ −0.25 e^(−d/15)) from a prior in which they are drawn to the dog (the truth's
    response with the dog's term negated, the information of recorded Strömbom episodes),
    the adaptive herder's estimate after an episode (about 200 s of herding) is a flight at
    every distance of 10–30 m, and at the distances it drives from (10–20 m) at least 70 %
    of the way from the prior to the truth, in every episode."""
    from herd_ros.herding.benchmark import herd_law_animals
    from herd_ros.herding.model_herder import record_episodes
    from herd_ros.herding.online_response import run_information
    st = Setting(14, 1, 0.3, family='herd-law')
    law = herd_law_animals(st)
    animals = slice(0, 14)
    truth = np.concatenate([[law.damping[animals].mean()],
                            law.profile_coef[animals].mean(axis=0),
                            law.own_coef[animals, 0].mean(axis=0)])
    B = law.profile.size
    prior_theta = truth * np.r_[np.ones(1 + B), -np.ones(law.own_profile.size)]
    info, rows = run_information(record_episodes(Setting(14, 1, 0.3), seeds=range(3)),
                                 law.profile, law.own_profile)
    prior = LearnedResponse(prior_theta, law.profile, law.own_profile, 60.0, info / rows, {})
    d = np.linspace(10.0, 30.0, 5)
    flight = law.own_profile.features(d) @ truth[1 + B:]
    drawn = law.own_profile.features(d) @ prior_theta[1 + B:]
    assert (drawn > 0).all()
    herder = ModelHerder(prior)
    state = {}

    def policy(P, dogs, goal, sheep, shepherd, st_):
        state.update(st_)
        return herder(P, dogs, goal, sheep, shepherd, st_)
    run_episodes(st, policy, range(4))
    fitted = law.own_profile.features(d) @ state['online'].theta[:, 1 + B:].T
    assert (fitted < 0).all(), fitted.T
    miss = np.abs(fitted - flight[:, None]) / np.abs(drawn - flight)[:, None]
    assert miss[d <= 20].max() < 0.3, (fitted.T, flight)
