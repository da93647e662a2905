"""Self-calibration: a session that chooses experiments and estimates the calibration.

:mod:`~odomgym.selfcal.session` (the experiment menu, the two estimators, ``SelfCalSession`` and
its observation layout), driven alike by ``SelfCalibration-v1``, the training vector env and
the ``selfcal`` calibrator; :mod:`~odomgym.selfcal.episodes` (a session on a hidden true robot,
episodes stepped in one physics batch, the validation and the guarded reward), the engine the
env and the training vector env share.
"""
