"""The fast paths of ``odomgym diagnose`` give every number bit for bit as the plain ones.

Each speed-up of the workflow (one filter pass for both scores, cached evaluations, compiled
replay stages) is checked here against the slower path it replaced, kept as the reference:
equality of the bytes, not a tolerance. The threaded evaluation's identity is tested in
``tests/test_discover.py``.
"""

from __future__ import annotations

import numpy as np
from alien_robot import generate_session

from odomgym.diagnose.fit import Dataset
from odomgym.diagnose.likelihood import SensorNoise, run_likelihood, run_scores
from odomgym.diagnose.replay import replay_run
from odomgym.effects import EFFECTS
from odomgym.robot import RobotSpec

MODEL = RobotSpec(wheel_diameter=0.084, wheelbase=0.2, ticks_per_rev=2796.8)
SENSOR = SensorNoise(0.002, 0.005)


def _bits(value: float) -> bytes:
    return np.float64(value).tobytes()


def test_one_filter_pass_gives_both_scores_bit_identical() -> None:
    """:func:`run_scores` runs the filter once when no wheel jump is expected and twice with
    bumps; either way its log-likelihood is :func:`run_likelihood`'s with the jump mixture and
    its whitened innovations are those with the jumps as their variance."""
    runs = generate_session({"sideslip": {"value": 0.03}}, np.random.default_rng(5))[:4]
    data = Dataset.of(runs, 0.25)
    rough = EFFECTS["floor_roughness"].write(MODEL, {"k_left": 3e-4, "k_right": 2e-4})
    bumpy = EFFECTS["floor_bumps"].write(rough, {"rate": 0.3, "heading_jump": 0.004})
    for spec in (MODEL, rough, bumpy):
        for run, mask in zip(data.runs, data.masks, strict=True):
            rep = replay_run(run, spec)
            mixture = run_likelihood(run, rep, spec, SENSOR, mask)
            gaussian = run_likelihood(run, rep, spec, SENSOR, mask, gaussian_jumps=True)
            loglik, white = run_scores(run, rep, spec, SENSOR, mask, whitened=True)
            assert white is not None
            assert _bits(loglik) == _bits(mixture.loglik)
            assert white.tobytes() == gaussian.whitened.tobytes()
            alone, none = run_scores(run, rep, spec, SENSOR, mask, whitened=False)
            assert none is None
            assert _bits(alone) == _bits(mixture.loglik)
        if spec is bumpy:  # the jumps matter here: the two filters really differ
            assert mixture.whitened.tobytes() != gaussian.whitened.tobytes()
