"""Self-calibration: a session that chooses experiments and estimates the calibration.

:mod:`~odomgym.selfcal.menu` (the experiments a session may choose),
:mod:`~odomgym.selfcal.estimators` (the trajectory filter and the end-pose fit),
:mod:`~odomgym.selfcal.session` (``SelfCalSession``, its books and observation layout), driven
alike by ``SelfCalibration-v1``, the training vector env and the ``selfcal`` calibrator; and
:mod:`~odomgym.selfcal.episodes` (a session on a hidden true robot, episodes stepped in one
physics batch, the validation and the guarded reward), the engine the env and the training
vector env share.
"""
