"""The odometry layer: dead reckoning from encoder counts, the run record and its measures.

:mod:`~odomgym.odometry.calibration` (``Calibration``, batched ``Odometry``),
:mod:`~odomgym.odometry.runs` (``Run``, one record for simulated and measured runs, and its
replay), :mod:`~odomgym.odometry.umbmark_measures` (UMBmark's centres of gravity and
E_max,syst) and :mod:`~odomgym.odometry.optiodom_measures` (the OptiOdom evaluation measures).
Imports only the robot spec and the modules below it: a measured run is read, replayed and
judged without the simulator. Units: metres, radians.
"""
