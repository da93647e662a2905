"""The two-truck vehicle (the CLAPPER, Borenstein 1995) and the encoder trailer (§7).

:mod:`~odomgym.vehicle.spec` (``VehicleSpec``, its presets and encoder readings),
:mod:`~odomgym.vehicle.estimator` (the internal estimator interface a vehicle's on-board
estimator implements, and plain dead reckoning), :mod:`~odomgym.vehicle.ipec` (IPEC, the
paper's estimator), :mod:`~odomgym.vehicle.paths` (the §6 paths),
:mod:`~odomgym.vehicle.cable_layout` (the cables laid across them),
:mod:`~odomgym.vehicle.controller` (the trucks' low-level controller),
:mod:`~odomgym.vehicle.trial` (``VehicleTrial`` and ``drive_vehicles``) and
:mod:`~odomgym.vehicle.paper_runs` (the §6 experiments as seeded sets of runs). Units: metres,
radians, seconds.
"""
