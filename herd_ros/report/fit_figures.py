"""PNG figures of a herd fit, after Schwager et al. (2007) Figs. 2–6 (matplotlib, Agg)."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from herd_ros.estimation.herd_fit import HerdFit, aligned_positions  # noqa: E402
from herd_ros.estimation.validation import agent_terms  # noqa: E402
from herd_ros.model.space_use_field import home_drift, subset_home  # noqa: E402
from herd_ros.simulation.statistics import STATISTICS  # noqa: E402


def _grid_of(n):
    cols = int(np.ceil(np.sqrt(n)))
    return int(np.ceil(n / cols)), cols


def interaction_figure(summary: dict, path: Path):
    """Fig. 2: F_ij(d) per ordered pair with its 95 % band (positive = attraction)."""
    pairs = summary['interaction']
    rows, cols = _grid_of(len(pairs))
    fig, axes = plt.subplots(rows, cols, figsize=(3.6 * cols, 2.8 * rows), squeeze=False)
    for ax, (name, c) in zip(axes.flat, pairs.items()):
        d = np.asarray(c['distance'])
        ax.fill_between(d, c['lower95'], c['upper95'], color='C0', alpha=0.25, label='95 %')
        ax.plot(d, c['force'], 'C0')
        ax.axhline(0, color='k', lw=0.6)
        tag = '' if c['identifiable'] else ' (weakly identified)'
        ax.set_title(f'{name}{tag}', fontsize=8)
        ax.set_xlabel('distance d (m)', fontsize=8)
        ax.set_ylabel('F(d) (m/s per step)', fontsize=8)
        ax.tick_params(labelsize=7)
    for ax in list(axes.flat)[len(pairs):]:
        ax.axis('off')
    fig.suptitle('Interaction force F_ij(d) = θ1 − θ2/d over the observed distances')
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def profile_figure(fit: HerdFit, path: Path):
    """The shared law's distance profiles: F_i(d) pooled over the neighbours, and H_ik(d) of
    every distinguished agent k, each agent thin and the herd mean with its 95 % band
    (from the agents' parameter covariances, the agents' fits being independent)."""
    model = fit.model
    blocks = [('pooled neighbours: F(d)', model.profile, model.profile_coef, 1, None)]
    B = model.profile.size
    for s, k in enumerate(model.own_agents):
        Bo = model.own_profile.size
        blocks.append((f'{k}: H(d), own profile', model.own_profile, model.own_coef[:, s],
                       1 + B + s * Bo, k))
    fig, axes = plt.subplots(1, len(blocks), figsize=(4.6 * len(blocks), 3.4), squeeze=False)
    for ax, (title, prof, coef, start, who) in zip(axes.flat, blocks):
        d = np.linspace(0.0, prof.radius, 200)
        psi = prof.features(d)                                          # (D, B)
        # the herd mean is over the ordinary agents; a distinguished agent's own pooled
        # profile (how a dog keeps to the flock) is drawn apart
        rows = [i for i, a in enumerate(model.agents)
                if a != who and (who is not None or a not in model.own_agents)]
        for i in rows:
            ax.plot(d, psi @ coef[i], color='0.7', lw=0.6)
        if who is None:
            for k in model.own_agents:
                ax.plot(d, psi @ coef[model.agents.index(k)], 'C1', lw=1.2, label=k)
        mean = psi @ coef[rows].mean(axis=0)
        var = np.zeros_like(d)
        for i in rows:
            a = model.agents[i]
            C = fit.fits[a].theta_cov
            # a distinguished agent's fit has no block with itself: later blocks sit earlier
            at = start
            if who is not None and a in model.own_agents \
                    and model.own_agents.index(a) < model.own_agents.index(who):
                at -= prof.size
            sl = slice(at, at + prof.size)
            var += np.einsum('db,bc,dc->d', psi, C[sl, sl], psi)
        half = 1.96 * np.sqrt(var) / len(rows)
        ax.fill_between(d, mean - half, mean + half, color='C0', alpha=0.3, label='mean ± 95 %')
        ax.plot(d, mean, 'C0', lw=2)
        ax.axhline(0, color='k', lw=0.6)
        ax.set_title(title, fontsize=9)
        ax.set_xlabel('distance d (m)', fontsize=8)
        ax.set_ylabel('m/s² (> 0 attracts)', fontsize=8)
        ax.tick_params(labelsize=7)
        ax.legend(fontsize=7)
    fig.suptitle('Shared law: distance profiles (grey: each agent; blue: their mean)')
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def field_figure(fit: HerdFit, runs, path: Path, n_arrows: int = 20):
    """Fig. 3: each agent's environment vector field g_i with its centres and its path."""
    model = fit.model
    rows, cols = _grid_of(model.n_agents)
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 4.0 * rows), squeeze=False)
    xmin, xmax, ymin, ymax = fit.grid.bounds
    gx, gy = np.meshgrid(np.linspace(xmin, xmax, n_arrows), np.linspace(ymin, ymax, n_arrows))
    pts = np.column_stack([gx.ravel(), gy.ravel()])
    for i, (ax, a) in enumerate(zip(axes.flat, model.agents)):
        _, _, basis, field_u, field_v = agent_terms(model, a)
        phi = basis.features(pts)
        g = np.column_stack([phi @ field_u, phi @ field_v])
        pull = home_drift(subset_home(model.meta, [i]), pts[:, None, :])  # long-run; else 0
        g = g + (pull[:, 0] if np.ndim(pull) else pull)
        for r in runs:
            p = aligned_positions(r, model.agents)[:, i]
            ax.plot(p[:, 0], p[:, 1], color='0.6', lw=0.4)
        if np.any(g):                      # a model without a field has no arrows
            ax.quiver(pts[:, 0], pts[:, 1], g[:, 0], g[:, 1], color='C3', angles='xy')
            ax.plot(basis.centers[:, 0], basis.centers[:, 1], 'k+', ms=6)
            ax.set_title(f'{a}: field g (arrows), centres (+), path', fontsize=8)
        else:
            ax.set_title(f'{a}: path (no field in the model)', fontsize=8)
        ax.set_aspect('equal')
        ax.tick_params(labelsize=7)
    for ax in list(axes.flat)[model.n_agents:]:
        ax.axis('off')
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def whiteness_figure(summary: dict, path: Path):
    """Fig. 4: autocorrelation of velocity vs residual (x component) with 90/95 % bands."""
    agents = list(summary['agents'])
    rows, cols = _grid_of(len(agents))
    fig, axes = plt.subplots(rows, cols, figsize=(4.0 * cols, 3.0 * rows), squeeze=False)
    for ax, a in zip(axes.flat, agents):
        s = summary['agents'][a]
        av, ar = np.asarray(s['acf_velocity']), np.asarray(s['acf_residual'])
        n = s['whiteness_residual']['n']
        # each series its own lags: over gaps the two have different counts present
        # (estimation/whiteness.py), so their maximum lags may differ
        ax.plot(np.arange(1, len(av)), av[1:, 0], 'C0.-', ms=3, label='velocity')
        ax.plot(np.arange(1, len(ar)), ar[1:, 0], 'C3.-', ms=3, label='residual')
        if n > 0:
            for z, ls in ((1.645, ':'), (1.96, '--')):
                ax.axhline(z / np.sqrt(n), color='k', ls=ls, lw=0.7)
                ax.axhline(-z / np.sqrt(n), color='k', ls=ls, lw=0.7)
        wr, wv = s['whiteness_residual'], s['whiteness_velocity']

        def share(x):
            return 'n/a' if not np.isfinite(x) else f'{x:.0%}'
        ax.set_title(f'{a}: inside 90 % band: residual {share(wr["inside_90"])}, '
                     f'velocity {share(wv["inside_90"])}', fontsize=8)
        ax.set_xlabel('lag (steps)', fontsize=8)
        ax.legend(fontsize=7)
        ax.tick_params(labelsize=7)
    for ax in list(axes.flat)[len(agents):]:
        ax.axis('off')
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def trajectories_figure(real_runs, sim_runs, agents, path: Path, title='simulated vs real',
                        labels=('real', 'simulated')):
    """Fig. 5: simulated vs real trajectories side by side."""
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.6), sharex=True, sharey=True)
    for ax, runs, label in zip(axes, (real_runs, sim_runs), labels):
        for r in runs:
            idx = [r.agents.index(a) for a in agents if a in r.agents]
            for k, i in enumerate(idx):
                ax.plot(r.positions[:, i, 0], r.positions[:, i, 1], color=f'C{k % 10}', lw=0.6,
                        label=r.agents[i] if r is runs[0] else None)
        ax.set_title(label)
        ax.set_aspect('equal')
        ax.set_xlabel('x east (m)')
    axes[0].set_ylabel('y north (m)')
    axes[0].legend(fontsize=7)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def statistics_figure(real: dict, other: dict, path: Path, labels=('real', 'simulated')):
    """Fig. 6: per-agent mean/std of distance to the others and of speed, bars side by side."""
    agents = list(real)
    fig, axes = plt.subplots(1, 4, figsize=(14, 3.4))
    x = np.arange(len(agents))
    for ax, stat in zip(axes, STATISTICS):
        ax.bar(x - 0.2, [real[a][stat] for a in agents], 0.4, label=labels[0])
        ax.bar(x + 0.2, [other[a][stat] if a in other else np.nan for a in agents], 0.4,
               label=labels[1])
        ax.set_xticks(x, agents, rotation=45, fontsize=7)
        ax.set_title(stat.replace('_', ' ') + (' (m)' if 'distance' in stat else ' (m/s)'))
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def alignment_figure(model, path: Path):
    """The learned alignment kernel K(d) (:mod:`herd_ros.model.alignment`): each agent's
    thin, the herd's mean with its 95 % band, and the bump centres."""
    al = model.alignment
    d = np.linspace(0.0, al.kernel.profile.radius, 200)
    fig, ax = plt.subplots(figsize=(5.2, 3.6))
    for i in range(len(al.coef)):
        ax.plot(d, al.curve(d, i), color='0.7', lw=0.6)
    mean, se = al.herd_curve(d)
    ax.fill_between(d, mean - 1.96 * se, mean + 1.96 * se, color='C2', alpha=0.3,
                    label='herd mean ± 95 %')
    ax.plot(d, mean, 'C2', lw=2)
    ax.plot(al.kernel.profile.centers, al.curve(np.asarray(al.kernel.profile.centers)),
            'o', color='C2', ms=4)
    ax.axhline(0, color='k', lw=0.6)
    ax.set_xlabel('distance d (m)')
    ax.set_ylabel('K(d) (> 0: matches the neighbour)')
    ax.set_title(f'Velocity alignment: {al.kernel.describe()}', fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_fit_figures(fit: HerdFit, summary: dict, train_runs, out_dir) -> list[Path]:
    """The figures of the fit report into ``out_dir`` (the interaction figure only for a
    model with pairwise interactions); returns their paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    if summary['interaction']:           # pairwise interactions in the model
        paths.append(out / 'fig2_interaction.png')
        interaction_figure(summary, paths[-1])
    elif hasattr(fit.model, 'profile_coef') and np.any(fit.model.profile_coef):
        paths.append(out / 'fig2_profiles.png')
        profile_figure(fit, paths[-1])
    if getattr(fit.model, 'alignment', None) is not None:
        paths.append(out / 'fig2_alignment.png')
        alignment_figure(fit.model, paths[-1])
    paths.append(out / 'fig3_field.png')
    field_figure(fit, train_runs, paths[-1])
    paths.append(out / 'fig4_whiteness.png')
    whiteness_figure(summary, paths[-1])
    paths.append(out / 'fig5_trajectories.png')
    trajectories_figure(train_runs, summary['_simulated_runs'], fit.model.agents, paths[-1])
    st = summary['statistics']
    paths.append(out / 'fig6_statistics.png')
    statistics_figure(st['real'], st['simulated'], paths[-1])
    return paths
