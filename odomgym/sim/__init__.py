"""The simulation layer: the pymunk World and what drives a robot through it.

:mod:`~odomgym.sim.world` (the batched World), :mod:`~odomgym.sim.chipmunk_link` (its exchange
with Chipmunk by address), :mod:`~odomgym.sim.cables` (a wheel crossing a cable),
:mod:`~odomgym.sim.routes` (squares, straights, spins and the progress along them),
:mod:`~odomgym.sim.driver` (the reference driver), :mod:`~odomgym.sim.trial` (World +
odometry + route, stepped as one compiled call), and the two driving loops that turn them into
runs: :mod:`~odomgym.sim.route_runs` (routes by the reference driver, a batch of robots at
once) and :mod:`~odomgym.sim.arc_runs` (circles and free paths by the robot's own (v, ω)
controller). Imports the odometry layer and below, never
a lab, a vehicle or an env. Units: metres, radians, seconds.
"""
