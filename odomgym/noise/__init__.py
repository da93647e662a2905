"""The noise layer: the random part of odometry error (Chong & Kleeman 1997).

:mod:`~odomgym.noise.covariance` (closed forms of the pose covariance),
:mod:`~odomgym.noise.montecarlo` (its vectorised Monte Carlo check),
:mod:`~odomgym.noise.fit` (estimating k_L, k_R from runs) and :mod:`~odomgym.noise.experiment`
(the paper's §6.3 experiment run in simulation, its reports and plot). Units: metres, radians;
k_L, k_R in √m.
"""
