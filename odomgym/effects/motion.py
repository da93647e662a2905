"""Contact-velocity effects: a toed-in wheel pair (crab), yaw skid under lateral acceleration and a
skid-steer robot's apparent track that moves with the turn.

All three act on the no-slip velocities of the two wheel contacts (``World.ground_velocity``) before
the floor does; the chassis follows through the friction-limited pivot joints, exactly as it
follows the plain rolling velocities. Split each contact velocity into the common translation
v̄ = (g_L + g_R)/2 and the differential part g_w − v̄ (the rotation about the axle midpoint):

* ``wheel_toe`` rotates the translation by τ: the robot crabs at τ to its heading while
  translating; rotation in place is untouched, so the heading is unaffected;
* ``turn_skid`` scales the differential part by max(0, 1 − κ·|v·ω₀|): yaw under-rotation that
  grows with the lateral acceleration v·ω₀ and vanishes in in-place turns (v = 0);
* ``skid_track`` scales the differential part by 1/(1 + ε/(1 + (|λ|/λ½)²)), λ = (v_L + v_R)/
  (v_R − v_L): yaw under-rotation largest in spins (λ = 0) and gone on straight paths.

The replay applies the same to one sampling interval (``docs/effects.md`` steps 4–6).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
from numpy.typing import NDArray

from odomgym._jit import kernel
from odomgym.effects.registry import Effect, Parameter, ReplayArrays, WorldHook, WorldView

__all__ = [
    "SkidSpeed",
    "SkidTrack",
    "TurnSkid",
    "WheelToe",
    "lateral_acceleration",
    "track_factor",
    "turning_lambda",
]

FloatArray = NDArray[np.float64]


class WheelToe(Effect):
    """A misaligned wheel pair: translation at a constant angle τ to the heading."""

    name = "wheel_toe"
    parameters = (
        Parameter("angle", "rad", 0.0, -0.2, 0.2, 1e-3, "direction of travel minus heading"),
    )
    summary = "misaligned wheels: the robot crabs sideways while translating, heading unaffected"
    reveals = (
        "one-way straight runs with ground truth along the track (cancels on closed loops and "
        "on out-and-back runs)"
    )
    confounded = (
        "a yaw misalignment of the ground-truth body frame (e.g. a motion-capture rigid body "
        "defined a little off the robot's axis) puts the same constant angle between the "
        "measured heading and the direction of travel; pose logs cannot tell the two apart, "
        "a check of the rigid-body alignment can"
    )

    @classmethod
    def skid_steer_refusal(cls, values: Mapping[str, float]) -> str:
        if cls.is_absent(values):
            return ""
        return (
            "a toe turns the contacts' no-slip velocity sideways, and a skid-steer robot's "
            "contacts take only their side's speed along the heading"
        )

    def world_hook(self, world: WorldView, values: FloatArray) -> WorldHook | None:
        return _ToeHook(values[:, 0].copy())

    stacked_replay = True  # sample by sample

    def replay(self, stage: str, values: Mapping[str, float], arrays: ReplayArrays) -> None:
        if stage == "body":
            arrays.crab = arrays.crab + values["angle"]


class _ToeHook(WorldHook):
    has_shape = True

    def __init__(self, angle: FloatArray) -> None:
        self.cos = np.cos(angle)
        self.sin = np.sin(angle)

    def shape(self, world: WorldView, h: float) -> None:
        _rotate_translation(world.ground_velocity, self.cos, self.sin)


@kernel
def _rotate_translation(ground_v: FloatArray, cos_a: FloatArray, sin_a: FloatArray) -> None:
    for i in range(ground_v.shape[0]):
        mx = 0.5 * (ground_v[i, 0, 0] + ground_v[i, 1, 0])
        my = 0.5 * (ground_v[i, 0, 1] + ground_v[i, 1, 1])
        rx = cos_a[i] * mx - sin_a[i] * my
        ry = sin_a[i] * mx + cos_a[i] * my
        for w in range(2):
            ground_v[i, w, 0] += rx - mx
            ground_v[i, w, 1] += ry - my


class TurnSkid(Effect):
    """Yaw under-rotation growing with lateral acceleration: dθ = dθ₀·max(0, 1 − κ|v·ω₀|)."""

    name = "turn_skid"
    parameters = (
        Parameter("gain", "s²/m", 0.0, 0.0, 10.0, 0.05, "yaw lost per m/s² of lateral accel."),
    )
    summary = "the robot under-turns on fast arcs (yaw lost grows with v·ω)"
    reveals = "arcs at two speeds (the loss grows with speed); absent in in-place turns"

    def world_hook(self, world: WorldView, values: FloatArray) -> WorldHook | None:
        return _SkidHook(values[:, 0].copy())

    stacked_replay = True  # sample by sample

    def replay(self, stage: str, values: Mapping[str, float], arrays: ReplayArrays) -> None:
        if stage == "body":
            gain = values["gain"]
            accel = lateral_acceleration(arrays)
            arrays.dtheta = arrays.dtheta * np.maximum(0.0, 1.0 - gain * accel)


def lateral_acceleration(arrays: ReplayArrays) -> FloatArray:
    """|v·ω₀| per interval [m/s²]: the speed ds/Δt times the incoming yaw rate dθ/Δt of the
    ``"body"`` stage, what ``turn_skid`` and ``skid_speed`` scale the yaw by (the World's hooks
    read the same from the rim speeds)."""
    accel: FloatArray = np.abs(arrays.ds * arrays.dtheta) / np.square(arrays.dt)
    return accel


class _SkidHook(WorldHook):
    has_shape = True

    def __init__(self, gain: FloatArray) -> None:
        self.gain = gain

    def shape(self, world: WorldView, h: float) -> None:
        _scale_rotation(world.ground_velocity, world.rim_speed, world.half_track, self.gain)


@kernel
def _scale_rotation(
    ground_v: FloatArray, rim: FloatArray, half_track: FloatArray, gain: FloatArray
) -> None:
    for i in range(ground_v.shape[0]):
        v = 0.5 * (rim[i, 0] + rim[i, 1])
        omega = (rim[i, 1] - rim[i, 0]) / (2.0 * half_track[i])
        factor = max(0.0, 1.0 - gain[i] * math.fabs(v * omega))
        mx = 0.5 * (ground_v[i, 0, 0] + ground_v[i, 1, 0])
        my = 0.5 * (ground_v[i, 0, 1] + ground_v[i, 1, 1])
        for w in range(2):
            ground_v[i, w, 0] = mx + factor * (ground_v[i, w, 0] - mx)
            ground_v[i, w, 1] = my + factor * (ground_v[i, w, 1] - my)


class SkidTrack(Effect):
    """A skid-steer robot's apparent track that widens as the turn tightens.

    Over one sampling interval with wheel travels d_L, d_R [m] and the path parameter
    λ = (d_L + d_R)/(d_R − d_L) [-] (0 in a spin, infinite on a straight step, 2R/b on an arc
    of radius R):

        dθ = dθ₀ / (1 + ε/(1 + (|λ|/λ½)²)),

    dθ₀ the yaw increment of the track E_b·b_n (step 3 of ``docs/effects.md``), ε ``excess``
    [-] and λ½ ``lambda_half`` [-]. The apparent track is then χ(λ) = E_b·(1 + ε/(1 + (|λ|/λ½)²))
    times the nominal one: E_b on straight paths and wide arcs (the asymptote), E_b·(1 + ε) in a
    spin, half the excess left at |λ| = λ½. It is the curvature-dependent factor of
    :mod:`odomgym.odometry.icr`, χ(λ) = χ_∞ + α/(1 + (β·|λ|)^p), at p = 2 with χ_∞ = E_b,
    α = E_b·ε, β = 1/λ½ — the form Wang et al. (2015, Sensors 15:9681) fit to a Pioneer 3-AT's
    ICR coefficient (there p = ½, χ_∞ = 1), whose fall with the path's straightening the ICR
    kinematics of Mandow et al. (2007, IROS) describe. ``docs/skid-steer.md`` shows it emerge
    from the World's tyre contacts.

    Computed as dθ₀/(1 + ε·u²/(u² + s²)) with u = (d_R − d_L)·λ½ and s = d_L + d_R, finite for
    every interval (a step that does not move keeps dθ₀ = 0).

    ε ≥ 0: the scrub only ever widens the track as the turn tightens (Mandow et al. 2007; Wang
    et al. 2015; the World's tyres, ``docs/skid-steer.md``). A negative excess — arcs
    under-turning against spins — is what ``turn_skid`` describes on a differential-drive
    robot, and on the OptiOdom robot's June sessions a free sign let ``skid_track`` stand in for
    it (ε = −0.006).
    """

    name = "skid_track"
    parameters = (
        Parameter("excess", "-", 0.0, 0.0, 5.0, 0.01, "extra track factor of a spin"),
        Parameter("lambda_half", "-", 2.0, 0.05, 100.0, 0.05, "|λ| where half the excess is left"),
    )
    summary = (
        "skid-steer scrub: the apparent track is wider in tight turns than on wide arcs (the "
        "robot under-turns more, the tighter it turns)"
    )
    reveals = "circles of several radii both ways and in-place spins (the factor moves with λ)"
    partners = ("wheelbase",)
    body_after = ("turn_skid", "skid_speed")

    @classmethod
    def shape_identified(cls, values: Mapping[str, float], travel: Sequence[FloatArray]) -> bool:
        """Whether the fitted fall of the apparent track happens where the data turns: the
        share 1/(1 + (|λ|/λ½)²) of the excess falls by at least :data:`SHARE_FALL` between a
        spin and the widest turns the logs hold (|λ| = :func:`turning_lambda`), i.e.
        λ½ ≤ 2·|λ|. A half-point further out leaves the factor nearly constant over every
        logged turn: one more constant track factor beside ``wheelbase``, with E_b and ε trading
        against each other (on a yaw-rate scrub of a differential-drive robot the pair went to
        E_b 0.72, ε 0.41, λ½ 50 where the widest arcs had |λ| = 10: a fall of 4 %). A half-point
        a little beyond the data is a shape it still spans (the World's scout2 in its first
        round: λ½ 17.5, widest turns 14.1, a fall of 39 %)."""
        widest = turning_lambda(travel)
        reach = widest * math.sqrt((1.0 - SHARE_FALL) / SHARE_FALL)
        return float(values.get("lambda_half", 0.0)) <= reach

    @classmethod
    def profile(
        cls, values: Mapping[str, float], travel: Sequence[FloatArray]
    ) -> tuple[str, list[dict[str, float]]] | None:
        """The half-point held at :data:`PROFILE_STEPS` values, quartering from the reach of the
        shape rule (:meth:`shape_identified`), each with an excess one step of its scale off its
        bound, while the excess and E_b are fitted: a profile over the half-point.

        Why: fitted jointly from one start, the three trade along a ridge. From the excess at 0,
        its bound, the residuals do not depend on λ½ and the fit stays at ε = 0 (the
        elastic-tyred robot of tests/independent_skid.py: ``wheelbase`` named first in 2 of 10);
        from a small excess it walks up the ridge to λ½ beyond every logged turn with E_b
        halved (ε 2.2, λ½ 36, E_b 0.5 on the same robot), where the shape rule refuses it.
        Held fixed, λ½ leaves the excess and E_b nearly linear in the residuals. ``diagnose``
        takes it only for a fit that came back at nothing (:func:`odomgym.diagnose.fit.
        fit_candidate`): from every fit's start it walked fits that had left the bound up the
        same ridge (the blind matrix's ``skid_track`` cells, 13 of 20 → 1)."""
        widest = turning_lambda(travel)
        if not widest > 0.0:
            return None
        reach = widest * math.sqrt((1.0 - SHARE_FALL) / SHARE_FALL)
        excess, half = cls.parameters
        start = max(float(values.get("excess", 0.0)), excess.absent + excess.scale)
        starts = []
        for k in range(PROFILE_STEPS):
            value = min(half.high, max(half.low, reach / 4.0**k))
            starts.append({**values, "excess": start, "lambda_half": value})
        return "lambda_half", starts

    @classmethod
    def is_absent(cls, values: Mapping[str, float]) -> bool:
        """Absent when ``excess`` is 0, whatever ``lambda_half``."""
        return float(values.get("excess", 0.0)) == 0.0

    def world_hook(self, world: WorldView, values: FloatArray) -> WorldHook | None:
        return _TrackHook(values[:, 0].copy(), values[:, 1].copy())

    stacked_replay = True  # sample by sample

    def replay(self, stage: str, values: Mapping[str, float], arrays: ReplayArrays) -> None:
        if stage == "body":
            arrays.dtheta = arrays.dtheta * track_factor(
                arrays.travel, values["excess"], values["lambda_half"]
            )


PROFILE_STEPS = 4
"""How many half-points :meth:`SkidTrack.profile` tries: the reach of the shape rule and three
quarterings below it (a factor 64: from the widest logged turns to turns 64 times tighter)."""

SHARE_FALL = 0.2
"""The least fall of the skid track's share of its excess, from a spin to the widest logged
turns, at which the data spans its shape (:meth:`SkidTrack.shape_identified`)."""

TURNING_QUANTILE = 0.95
"""The share of the logs' turning (weighted by |d_R − d_L|) whose |λ| lies at or below
:func:`turning_lambda`: the widest turns that carry at least 5 % of it count, a few wiggles of
a straight run (|λ| in the hundreds, tiny |d_R − d_L|) do not."""


def turning_lambda(travel: Sequence[FloatArray]) -> float:
    """The widest turns the logs hold, as a path parameter |λ| = |d_L + d_R|/|d_R − d_L| [-]:
    the :data:`TURNING_QUANTILE` quantile of |λ| over every interval of ``travel`` (per run
    (n, 2) wheel travels [m]), each weighted by its turning |d_R − d_L| (0 when nothing
    turns)."""
    if not travel:
        return 0.0
    steps = np.concatenate([np.asarray(t, dtype=np.float64).reshape(-1, 2) for t in travel])
    steps = steps[np.all(np.isfinite(steps), axis=1)]
    turn = np.abs(steps[:, 1] - steps[:, 0])
    moving = turn > 0.0
    if not np.any(moving):
        return 0.0
    lam = np.abs(steps[moving, 0] + steps[moving, 1]) / turn[moving]
    weight = turn[moving]
    order = np.argsort(lam, kind="stable")
    cumulative = np.cumsum(weight[order])
    k = int(np.searchsorted(cumulative, TURNING_QUANTILE * cumulative[-1]))
    return float(lam[order][min(k, len(order) - 1)])


def track_factor(travel: FloatArray, excess: float, lambda_half: float) -> FloatArray:
    """1/(1 + ε/(1 + (|λ|/λ½)²)) per interval (n,) for wheel travels ``travel`` (n, 2) [m]
    (:class:`SkidTrack`)."""
    u = (travel[:, 1] - travel[:, 0]) * lambda_half
    s = travel[:, 0] + travel[:, 1]
    u2 = u * u
    total = u2 + s * s
    share = np.divide(u2, total, out=np.zeros_like(u2), where=total > 0.0)
    factor: FloatArray = 1.0 / (1.0 + excess * share)
    return factor


class _TrackHook(WorldHook):
    has_shape = True

    def __init__(self, excess: FloatArray, lambda_half: FloatArray) -> None:
        self.excess = excess
        self.lambda_half = lambda_half

    def shape(self, world: WorldView, h: float) -> None:
        _scale_track(world.ground_velocity, world.rim_speed, self.excess, self.lambda_half)


@kernel
def _scale_track(
    ground_v: FloatArray, rim: FloatArray, excess: FloatArray, lambda_half: FloatArray
) -> None:
    for i in range(ground_v.shape[0]):
        u = (rim[i, 1] - rim[i, 0]) * lambda_half[i]
        s = rim[i, 0] + rim[i, 1]
        total = u * u + s * s
        share = u * u / total if total > 0.0 else 0.0
        factor = 1.0 / (1.0 + excess[i] * share)
        mx = 0.5 * (ground_v[i, 0, 0] + ground_v[i, 1, 0])
        my = 0.5 * (ground_v[i, 0, 1] + ground_v[i, 1, 1])
        for w in range(2):
            ground_v[i, w, 0] = mx + factor * (ground_v[i, w, 0] - mx)
            ground_v[i, w, 1] = my + factor * (ground_v[i, w, 1] - my)


class SkidSpeed(Effect):
    """A skid-steer robot's apparent track that narrows as the turn gets faster:
    dθ = dθ₀·(1 + g·|v·ω₀|), with v·ω₀ the lateral acceleration [m/s²] of the interval
    (dθ₀ the yaw increment before the skid track, v = ds/Δt, ω₀ = dθ₀/Δt) and g ``gain``
    [s²/m] ≥ 0. With ``skid_track`` beside it the apparent track is a function of the turn
    radius *and* the speed, χ(λ, v·ω) = E_b·(1 + ε/(1 + (|λ|/λ½)²))/(1 + g·|v·ω|) to first
    order: the speed-dependent ICR coefficient of Wang et al. (2015, Sensors 15:9681).

    Why it narrows: the friction that holds a skid-steer robot's contacts against the scrub
    must also supply the centripetal force m·v·ω, so in a fast tight turn the contacts slide
    more along the path and less across it, and the robot turns more for the same rim speeds.
    The World's Scout 2.0 shows it without any formula (``docs/skid-steer.md``: a turn
    commanded at 0.5 m, factor 1.617 at 0.2 m/s, 1.544 at 0.9 m/s; a spin keeps 1.667 at
    every speed, v = 0; a 5 m turn keeps 1.252, its v·ω small). An apparent track that widens
    with speed is ``turn_skid`` (dθ₀·max(0, 1 − κ·|v·ω₀|)), so this one's sign is fixed: the
    two are not one effect named twice.

    ``diagnose`` proposes it to every robot, of either class (issue 43: no candidate filtered
    by the robot's class). A differential-drive robot has no scrub to relieve, and on its logs
    the fit leaves the gain at 0 unless the data want it (``docs/skid-steer.md``: the June
    sessions and the blind matrix, re-run with it offered)."""

    name = "skid_speed"
    parameters = (
        Parameter(
            "gain", "s²/m", 0.0, 0.0, 2.0, 0.01, "track narrowing per m/s² of lateral accel."
        ),
    )
    summary = (
        "skid-steer scrub relieved by speed: the apparent track narrows (the robot turns more) "
        "as the lateral acceleration v·ω grows"
    )
    reveals = (
        "circles of one radius at two or more speeds, tight ones (the factor moves with v·ω); "
        "absent in spins and on straight paths"
    )

    def world_hook(self, world: WorldView, values: FloatArray) -> WorldHook | None:
        # _scale_rotation's factor max(0, 1 − κ·|v·ω|) at κ = −g is 1 + g·|v·ω| (never clipped)
        return _SkidHook(-values[:, 0])

    stacked_replay = True  # sample by sample

    def replay(self, stage: str, values: Mapping[str, float], arrays: ReplayArrays) -> None:
        if stage == "body":
            arrays.dtheta = arrays.dtheta * (1.0 + values["gain"] * lateral_acceleration(arrays))
