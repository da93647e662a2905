"""The lab layer: where a calibrator asks for experiments and receives runs.

:mod:`~odomgym.lab.experiment` (``Experiment``, its kinds, the ``Lab`` protocol),
:mod:`~odomgym.lab.simulated` (``SimLab`` and the batched simulation of runs),
:mod:`~odomgym.lab.lockstep` (a population of calibrators simulated as one batch),
:mod:`~odomgym.lab.recorded` (``RecordedLab``: the same protocol over measured sessions),
:mod:`~odomgym.lab.plans` (squares and straights driven as a batch, their UMBmark summary),
:mod:`~odomgym.lab.population` (the robots and floors a calibration is judged on) and
:mod:`~odomgym.lab.report` (tables and plots of runs). Imports the simulation, odometry and
data layers, never a vehicle, an env or a calibrator.
"""
