"""Figures of the herding benchmark: success rates with their Wilson intervals, and a GIF
of one episode per herder (:mod:`herd_ros.herding.benchmark`)."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from herd_ros.herding.benchmark import FIELD, GOAL, GOAL_RADIUS  # noqa: E402


def success_figure(rows: list, path: Path):
    """Success rate per setting, one bar per herder, with the 95 % interval."""
    settings = []
    for r in rows:
        key = r['setting']['n_animals'], r['setting']['n_herders'], r['setting']['noise'], \
            r['setting']['neighbours']
        if key not in settings:
            settings.append(key)
    herders = list(dict.fromkeys(r['herder'] for r in rows))
    width = 0.8 / len(herders)
    fig, ax = plt.subplots(figsize=(max(5.0, 1.2 * len(settings) + 2), 3.8))
    for h, name in enumerate(herders):
        xs, ys, lo, hi = [], [], [], []
        for r in rows:
            if r['herder'] != name:
                continue
            s = r['setting']
            k = settings.index((s['n_animals'], s['n_herders'], s['noise'], s['neighbours']))
            xs.append(k + (h - (len(herders) - 1) / 2) * width)
            ys.append(r['success'])
            lo.append(max(0.0, r['success'] - r['ci'][0]))
            hi.append(max(0.0, r['ci'][1] - r['success']))
        ax.bar(xs, ys, width, yerr=[lo, hi], capsize=3, label=name)
    ax.set_xticks(range(len(settings)))
    ax.set_xticklabels([f'N={n}\n{d} herder{"s" if d > 1 else ""}\ne={e:g} n={k}'
                        for n, d, e, k in settings], fontsize=7)
    ax.set_ylim(0, 1.05)
    ax.set_ylabel('success (95 % Wilson interval)')
    ax.legend(fontsize=8)
    ax.set_title('Herding into a 15 m goal on a 150 m field', fontsize=9)
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
