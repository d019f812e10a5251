"""What the estimator reports about its learning (``/diagnostics``), from an
:class:`~herd_ros.estimation.online_fit.OnlineHerdEstimator`: the herd's running one-step
skill against the naive baselines, and per agent its samples, residual, whiteness (the lag-1
autocorrelation against its 95 % band) and the condition of P."""
from __future__ import annotations

#: agents with more samples than this and a residual that is not white are flagged
WHITENESS_MIN_SAMPLES = 50


def herd_skill(core) -> dict:
    """The herd's running one-step RMS (m): model (predicted before each update), constant
    velocity, stay-put, and how many predictions they average."""
    sk = core.skill()
    return {'model_rms': sk['model_herd'], 'constant_velocity_rms': sk['constant_velocity_herd'],
            'stay_put_rms': sk['stay_put_herd'], 'predictions': int(sk['predictions'].sum())}


def agent_statuses(core) -> list[tuple[str, bool, str, dict]]:
    """(agent, warn, message, values) of every agent."""
    d, sk = core.diagnostics(), core.skill()
    out = []
    for i, agent in enumerate(core.agents):
        samples = int(d['samples'][i])
        message = 'learning' if samples > 0 else 'no samples yet'
        if samples > WHITENESS_MIN_SAMPLES and not d['white'][i]:
            message = 'residual not white: the model misses something'
        out.append((agent, samples == 0, message, {
            'samples': samples, 'residual_rms': float(d['residual_rms'][i]),
            'lag1_autocorrelation': float(d['lag1_autocorrelation'][i]),
            'white_band_95': float(d['white_band'][i]),
            'condition_P': float(d['condition'][i]),
            'skill_model_rms': float(sk['model'][i]),
            'skill_constant_velocity_rms': float(sk['constant_velocity'][i]),
            'skill_stay_put_rms': float(sk['stay_put'][i])}))
    return out
