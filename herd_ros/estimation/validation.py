"""The paper's validation of a fitted herd model, as numbers (the figures draw from these).

* one-step and k-step RMS of the model next to constant velocity and stay-put (and, one
  step, the damping-only model fitted on the same training data), on held-out data (a
  time split);
* whiteness of the velocity and of the residual w_i (autocorrelation bands, Ljung–Box),
  and how much of the residual the herd shares (:mod:`~herd_ros.estimation.shared_residuals`);
* interaction force curves F_ij(d) = θ1_ij − θ2_ij/d with 95 % confidence bands over the
  observed distances, and equilibrium distances with their intervals;
* simulated vs real herd statistics (simulation of the learned laws with noise from Q_i).
"""
from __future__ import annotations

import numpy as np

from herd_ros.estimation.herd_fit import HerdFit, aligned_positions
from herd_ros.estimation.shared_residuals import shared_residuals
from herd_ros.estimation.whiteness import whiteness
from herd_ros.nan_stats import empty_slices_quiet
from herd_ros.simulation.herd_simulator import simulate_from_each
from herd_ros.simulation.prediction import damping_only_fit, k_step_rms, one_step_rms
from herd_ros.simulation.statistics import herd_statistics, relative_differences
from herd_ros.trajectory import HerdTrajectory

from herd_ros.report.intervals import Z95  # noqa: E402


def force_curves(fit: HerdFit, runs: list[HerdTrajectory], n_points: int = 100) -> dict:
    """F_ij(d) with 95 % bands over the 1st–99th percentile of the observed d_ij."""
    model = fit.model
    agents = model.agents
    n = len(agents)
    out = {}
    for i, a in enumerate(agents):
        law = model.laws[a]
        cov = fit.fits[a].theta_cov if a in fit.fits else None
        for k, b in enumerate(law.neighbors):
            j = agents.index(b)
            d_obs = np.concatenate([np.sqrt(((aligned_positions(r, agents)[:, j]
                                              - aligned_positions(r, agents)[:, i]) ** 2).sum(-1))
                                    for r in runs])
            lo, hi = np.percentile(d_obs, [1, 99])
            d = np.linspace(max(lo, 1e-3), hi, n_points)
            f = law.theta1[k] - law.theta2[k] / d
            i1, i2 = 1 + k, 1 + (n - 1) + k
            if cov is not None:
                c11, c22, c12 = cov[i1, i1], cov[i2, i2], cov[i1, i2]
            else:
                se = law.theta_se
                c11, c22, c12 = se[i1] ** 2, se[i2] ** 2, 0.0
            sd = np.sqrt(np.clip(c11 + c22 / d ** 2 - 2 * c12 / d, 0, None))
            t1, t2 = law.theta1[k], law.theta2[k]
            s1, s2 = np.sqrt(c11), np.sqrt(c22)
            out[f'{a}->{b}'] = {
                'distance': d.tolist(), 'force': f.tolist(),
                'lower95': (f - Z95 * sd).tolist(), 'upper95': (f + Z95 * sd).tolist(),
                'theta1': float(t1), 'theta1_ci95': [float(t1 - Z95 * s1), float(t1 + Z95 * s1)],
                'theta2': float(t2), 'theta2_ci95': [float(t2 - Z95 * s2), float(t2 + Z95 * s2)],
                'equilibrium_distance': float(t2 / t1) if t1 > 0 else None,
                'observed_distance_range': [float(lo), float(hi)],
                'identifiable': bool(abs(t1) > Z95 * s1 and abs(t2) > Z95 * s2),
            }
    return out


def damping_only_rms(train, runs, agents) -> dict:
    """One-step RMS (m) on ``runs`` of the damping-only model p̂ = p + a (p − p_prev), one
    a per agent fitted on ``train`` (:func:`damping_only_fit`): {agent: RMS, 'herd': RMS}."""
    a = damping_only_fit(np.concatenate([aligned_positions(r, agents) for r in train]))
    errs = []
    for r in runs:
        p = aligned_positions(r, agents)
        if len(p) >= 3:
            errs.append(p[1:-1] + a[None, :, None] * (p[1:-1] - p[:-2]) - p[2:])
    e = np.concatenate(errs)
    sq = (e ** 2).sum(-1)
    with empty_slices_quiet():
        out = {ag: float(np.sqrt(np.nanmean(sq[:, i]))) for i, ag in enumerate(agents)}
        out['herd'] = float(np.sqrt(np.nanmean(sq)))
    return out


def last_raw_fix_rms(runs, agents) -> dict | None:
    """One-step RMS (m) of the last raw fix for GPS input: the prediction of p^{k+1} is the
    agent's last raw fix at or before tick k (what a user has with no filter), on the
    samples the other baselines use (p^{k−1}, p^k, p^{k+1} present); None when the runs
    carry no raw fixes (a trajectory file). {agent: RMS, 'herd': RMS}."""
    from herd_ros.simulation.prediction import last_raw_fix_ahead
    errs = []
    for r in runs:
        if r.meta.get('raw_fixes') is None or r.n_steps < 3:
            continue
        p = aligned_positions(r, agents)
        have = np.isfinite(p[:-2, :, 0]) & np.isfinite(p[1:-1, :, 0])
        e = last_raw_fix_ahead(r, agents, 1)[2:] - p[2:]
        errs.append(np.where(have[..., None], e, np.nan))
    if not errs:
        return None
    sq = (np.concatenate(errs) ** 2).sum(-1)
    with empty_slices_quiet():
        out = {ag: float(np.sqrt(np.nanmean(sq[:, i]))) for i, ag in enumerate(agents)}
        out['herd'] = float(np.sqrt(np.nanmean(sq)))
    return out


def skill_lines(summary: dict) -> list[str]:
    """The skill table that leads a fit or report: herd RMS (m) of the model against
    constant velocity, stay-put and damping only, one step and k steps ahead."""
    ks = list(summary['k_step_rms']['model'])
    ev = summary['evaluated_on']
    lines = [f'prediction skill on {ev} data: herd RMS (m) k steps ahead',
             f'  {"k":>4} {"model":>9} {"const-vel":>10} {"stay-put":>9} {"damping":>9}']
    for k in ks:
        row = [summary['k_step_rms'][m].get(k, float('nan'))
               for m in ('model', 'constant_velocity', 'stay_put', 'damping_only')]
        lines.append(f'  {k:>4} ' + ' '.join(f'{v:>{w}.3f}' for v, w in zip(row, (9, 10, 9, 9))))
    return lines


def agent_terms(model, agent: str):
    """(damping, damping SE or None, field basis, field_u, field_v) of one agent of a
    pairwise (:class:`HerdModel`) or shared-law model."""
    i = model.agents.index(agent)
    if hasattr(model, 'laws'):
        law = model.laws[agent]
        se = float(law.theta_se[0]) if law.theta_se is not None else None
        return law.damping, se, law.basis, law.field_u, law.field_v
    se = float(model.theta_se[i][0]) if model.theta_se is not None else None
    return model.damping[i], se, model.bases[i], model.field_u[i], model.field_v[i]


def has_pairwise_interactions(model) -> bool:
    """A pairwise model with any non-zero pair term (a selected fit may have none)."""
    return hasattr(model, 'laws') and bool(np.any(model.theta1) or np.any(model.theta2))


def validate(fit: HerdFit, train: list[HerdTrajectory], test: list[HerdTrajectory],
             seed=0, ks=(1, 5, 10, 30)) -> dict:
    """Every number of the fit report (see the module docstring)."""
    model = fit.model
    held_out = [r for r in test if r.n_steps >= 3]
    evaluate_on = held_out if sum(r.n_steps - 2 for r in held_out) >= 20 else train
    summary = {'evaluated_on': 'held-out' if evaluate_on is held_out else 'training',
               'agents': {}}
    summary['one_step_rms'] = one_step_rms(model, evaluate_on)
    summary['one_step_rms']['damping_only'] = damping_only_rms(train, evaluate_on,
                                                               model.agents)
    raw = last_raw_fix_rms(evaluate_on, model.agents)
    if raw is not None:
        summary['one_step_rms']['last_raw_fix'] = raw
    a = damping_only_fit(np.concatenate([aligned_positions(r, model.agents) for r in train]))
    summary['k_step_rms'] = {m: {str(k): v for k, v in d.items()}
                             for m, d in k_step_rms(model, evaluate_on, ks, damping=a).items()}
    positions = [aligned_positions(r, model.agents) for r in evaluate_on]
    residuals = [model.residuals(p) for p in positions]          # once per run, not per agent
    for i, a in enumerate(model.agents):
        vel = [np.diff(p[:, i], axis=0) / model.dt for p in positions]
        res = [w[:, i] for w in residuals]
        wv, wr = whiteness(np.concatenate(vel)), whiteness(np.concatenate(res))
        damping, damping_se, basis, _, _ = agent_terms(model, a)
        summary['agents'][a] = {
            'damping': float(damping),
            'damping_se': damping_se,
            'field_centres': int(basis.size),
            'samples': int(fit.fits[a].n_samples) if a in fit.fits else None,
            'condition': float(fit.fits[a].condition) if a in fit.fits else None,
            'constrained': fit.fits[a].constrained if a in fit.fits else '',
            'noise_cov': model.noise_cov[model.agents.index(a)].ravel().tolist(),
            'whiteness_velocity': wv.as_dict(), 'whiteness_residual': wr.as_dict(),
            'acf_velocity': wv.acf.tolist(), 'acf_residual': wr.acf.tolist(),
        }
    summary['shared_residuals'] = shared_residuals(residuals, model.dt)
    summary['interaction'] = (force_curves(fit, train) if has_pairwise_interactions(model)
                              else {})
    if getattr(model, 'alignment', None) is not None:
        summary['alignment'] = model.alignment.summary(model.agents)
    sims = simulate_from_each(model, list(train), [seed + k for k in range(len(train))])
    real_stats, sim_stats = herd_statistics(train), herd_statistics(sims)
    summary['statistics'] = {'real': real_stats, 'simulated': sim_stats,
                             'relative_difference': relative_differences(real_stats, sim_stats)}
    summary['_simulated_runs'] = sims
    # free run from the start of the (longest) evaluation run for its length (issue 30)
    from herd_ros.simulation.free_run import free_run_fidelity
    summary['free_run'] = free_run_fidelity(model, max(evaluate_on, key=lambda r: r.n_steps))
    return summary
