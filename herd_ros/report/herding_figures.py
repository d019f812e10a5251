"""Figures of the herding benchmark: success rates with their Wilson intervals, and a GIF
of one episode per herder (:mod:`herd_ros.herding.benchmark`)."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from herd_ros.herding.benchmark import FIELD, GOAL, GOAL_RADIUS  # noqa: E402


def _key(row) -> tuple:
    s = row['setting']
    return s['n_animals'], s['n_herders'], s['noise'], s['neighbours'], s.get('family',
                                                                             'strombom')


def success_figure(rows: list, path: Path):
    """Per setting, one bar per herder: the success rate with its 95 % interval (left) and
    the median time of the successful episodes (right)."""
    settings = list(dict.fromkeys(_key(r) for r in rows))
    herders = list(dict.fromkeys(r['herder'] for r in rows))
    width = 0.8 / len(herders)
    fig, (ax, ax_t) = plt.subplots(1, 2, figsize=(max(8.0, 2.2 * len(settings) + 3), 3.9))
    for h, name in enumerate(herders):
        xs, ys, lo, hi, ts = [], [], [], [], []
        for r in rows:
            if r['herder'] != name:
                continue
            xs.append(settings.index(_key(r)) + (h - (len(herders) - 1) / 2) * width)
            ys.append(r['success'])
            lo.append(max(0.0, r['success'] - r['ci'][0]))
            hi.append(max(0.0, r['ci'][1] - r['success']))
            ts.append(r['median_time_s'] if r['median_time_s'] is not None else np.nan)
        ax.bar(xs, ys, width, yerr=[lo, hi], capsize=3, label=name)
        ax_t.bar(xs, ts, width, label=name)
    labels = [f'N={n}, {d} herder{"s" if d > 1 else ""}\ne={e:g} n={k}'
              + ('' if fam == 'strombom' else f'\n{fam}')
              for n, d, e, k, fam in settings]
    for a in (ax, ax_t):
        a.set_xticks(range(len(settings)))
        a.set_xticklabels(labels, fontsize=7)
        a.legend(fontsize=8)
    ax.set_ylim(0, 1.05)
    ax.set_ylabel('success (95 % Wilson interval)')
    ax_t.set_ylabel('median time to the goal (s)')
    fig.suptitle('Herding into a 15 m goal on a 150 m field', fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def episode_gif(shown: dict, path: Path, every: int = 10, fps: int = 12):
    """One episode per herder side by side (``shown``: herder -> (setting, frames))."""
    from matplotlib.animation import FuncAnimation, PillowWriter
    names = list(shown)
    fig, axes = plt.subplots(1, len(names), figsize=(3.6 * len(names), 3.6), squeeze=False)
    frames = max(len(f) for _, f in shown.values())
    artists = []
    for ax, name in zip(axes.flat, names):
        ax.set_xlim(0, FIELD)
        ax.set_ylim(0, FIELD)
        ax.set_aspect('equal')
        ax.add_patch(plt.Circle(GOAL, GOAL_RADIUS, color='C2', alpha=0.25))
        ax.set_title(f'{name}: {shown[name][0].label()}', fontsize=7)
        ax.tick_params(labelsize=6)
        herd = ax.plot([], [], '.', color='0.3', ms=4)[0]
        dogs = ax.plot([], [], 'o', color='C3', ms=5)[0]
        artists.append((herd, dogs, shown[name][1]))

    def draw(k):
        out = []
        for herd, dogs, traj in artists:
            P, D = traj[min(k * every, len(traj) - 1)]
            herd.set_data(P[:, 0], P[:, 1])
            dogs.set_data(D[:, 0], D[:, 1])
            out += [herd, dogs]
        return out

    anim = FuncAnimation(fig, draw, frames=int(np.ceil(frames / every)), blit=True)
    anim.save(path, writer=PillowWriter(fps=fps))
    plt.close(fig)
