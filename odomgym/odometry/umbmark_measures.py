"""UMBmark accuracy measures (Borenstein & Feng 1994, §3 and §6.3).

Return errors ε = (ε_x, ε_y, ε_θ) are true − odometry at the end of a square run, in the start
frame (:func:`odomgym.odometry.runs.return_error`). For each direction the *centre of gravity* is
the mean return position error (Eq. 3.2); the *measure of dead-reckoning accuracy for systematic
errors* is the larger of the two centres' distances from the origin, E_max,syst (Eq. 3.3).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["UMBmarkSummary", "centre_of_gravity", "e_max_syst", "summarize_umbmark"]

FloatArray = NDArray[np.float64]


def centre_of_gravity(errors: ArrayLike) -> FloatArray:
    """Mean (x_c.g., y_c.g.) [m] of return errors (n, ≥2) — Borenstein & Feng 1994, Eq. 3.2."""
    array = np.asarray(errors, dtype=float)
    if array.ndim != 2 or array.shape[0] == 0 or array.shape[1] < 2:
        raise ValueError(f"need return errors of shape (n>=1, >=2), got {array.shape}")
    return np.asarray(array[:, :2].mean(axis=0))


def e_max_syst(cw_errors: ArrayLike, ccw_errors: ArrayLike) -> float:
    """E_max,syst = max(r_c.g.,cw, r_c.g.,ccw) [m] — Borenstein & Feng 1994, Eq. 3.3."""
    return float(
        max(np.hypot(*centre_of_gravity(cw_errors)), np.hypot(*centre_of_gravity(ccw_errors)))
    )


@dataclass(frozen=True)
class UMBmarkSummary:
    """Centres of gravity, E_max,syst, second-compensation rule (Borenstein & Feng 1994, §6.3).

    Attributes:
        cg_cw, cg_ccw: centres of gravity (x, y) [m].
        e_max_syst: E_max,syst [m].
        sem: standard error of the mean return position error, σ/√n, the larger of the two
            directions [m] (σ of the distances of the runs from their centre of gravity).
        second_compensation_advised: E_max,syst > 3·SEM — the rule of thumb of §6.3 that a
            further calibration round is likely to help.
    """

    cg_cw: tuple[float, float]
    cg_ccw: tuple[float, float]
    e_max_syst: float
    sem: float
    second_compensation_advised: bool


def summarize_umbmark(cw_errors: ArrayLike, ccw_errors: ArrayLike) -> UMBmarkSummary:
    """All UMBmark measures of one bi-directional experiment."""
    cw = np.asarray(cw_errors, dtype=float)
    ccw = np.asarray(ccw_errors, dtype=float)
    cg_cw, cg_ccw = centre_of_gravity(cw), centre_of_gravity(ccw)
    sems = []
    for errors, cg in ((cw, cg_cw), (ccw, cg_ccw)):
        n = errors.shape[0]
        if n > 1:
            spread = np.hypot(errors[:, 0] - cg[0], errors[:, 1] - cg[1])
            sems.append(float(np.sqrt(np.sum(spread**2) / (n - 1)) / np.sqrt(n)))
        else:
            sems.append(float("nan"))
    sem = max(sems)
    emax = e_max_syst(cw, ccw)
    return UMBmarkSummary(
        cg_cw=(float(cg_cw[0]), float(cg_cw[1])),
        cg_ccw=(float(cg_ccw[0]), float(cg_ccw[1])),
        e_max_syst=emax,
        sem=sem,
        second_compensation_advised=bool(np.isfinite(sem) and emax > 3.0 * sem),
    )
