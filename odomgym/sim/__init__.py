"""The simulation layer: the pymunk World and what drives a robot through it.

:mod:`~odomgym.sim.world` (the batched World), :mod:`~odomgym.sim.chipmunk_link` (its exchange
with Chipmunk by address), :mod:`~odomgym.sim.cables` (a wheel crossing a cable),
:mod:`~odomgym.sim.routes` (squares, straights, spins and the progress along them),
:mod:`~odomgym.sim.driver` (the reference driver) and :mod:`~odomgym.sim.trial` (World +
odometry + route, stepped as one compiled call). Imports the odometry layer and below, never
a lab, a vehicle or an env. Units: metres, radians, seconds.
"""
