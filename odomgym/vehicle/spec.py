"""Two-truck vehicles joined by a compliant linkage: the CLAPPER of Borenstein 1995.

The CLAPPER is two differential-drive trucks (LabMates) whose centres are joined by a linkage
that lets them move almost force-free within its range: an absolute rotary encoder at each truck
centre measures the angle between the truck and the link, a linear encoder measures the distance
between the centres (Borenstein 1995, §2, Figs. 1-2). Comparing these internal measurements with
what each truck's wheel odometry says is Internal Position Error Correction (IPEC,
:mod:`odomgym.vehicle.ipec`).

:class:`VehicleSpec` describes such a vehicle (two robot specs, the link and its encoders) and
loads from TOML like the robot specs (``[vehicle]``, docs/specs.md). :func:`link_readings` turns
true truck poses into what the internal encoders report: quantised to their resolution, plus
their biases (the "unconventional systematic errors" of Borenstein 1995, §5.2).

Conventions: truck A is the front truck, B the rear one. The link direction θ_L points from B's
centre to A's; ψ_X = θ_X − θ_L is the angle of truck X to the link, wrapped to [−π, π)
(Borenstein 1995, Eqs. 10-11). Units: metres, radians, seconds.
"""

from __future__ import annotations

import dataclasses
import math
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from odomgym._jit import kernel
from odomgym.errors import (
    SpecError,
    load_named,
    locate_key,
    refuse_stray_keys,
    require_finite,
    require_positive,
    require_range,
)
from odomgym.io import atomic_write_text
from odomgym.robot import PRESETS, RobotSpec, load_robot
from odomgym.vehicle.estimator import LinkReading, check_poses

__all__ = [
    "ENCODER_TRAILER",
    "PAPER_ERRORS",
    "VEHICLES",
    "VehicleSpec",
    "calibrated",
    "link_readings",
    "load_vehicle",
]

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class VehicleSpec:
    """A two-truck vehicle with a compliant linkage between the truck centres.

    Attributes:
        truck_a, truck_b: the front and rear trucks (each with its own systematic errors).
        link_length: nominal centre distance l₀ the controller keeps [m] (Borenstein 1995,
            §3.3: 1 m).
        link_min, link_max: the ends of the linear bearing [m]; between them the link passes no
            force (§2), at them it is a hard stop. The paper does not give the range; ±0.1 m
            is assumed.
        sample_period: T_s, how often the encoders are read and IPEC runs [s] (§4.1: 40 ms).
        rotary_bits: resolution of the absolute rotary encoders, 2π/2^bits [rad] (§2: 10 bits,
            0.35°).
        rotary_bias_a, rotary_bias_b: constant bias of each rotary encoder [rad] (§5.2).
        linear_resolution: resolution of the linear encoder [m] (§2: 0.1 mm).
        linear_bias: constant bias of the link-length measurement [m] (§5.2: about 2 mm was
            suspected in the prototype, whose accuracy was ±3 mm).
        linear_eccentricity: the linear encoder's eccentricity [m] (§5.2 names it, "which
            changes the bias when the two trucks rotate relative to the compliant linkage", but
            gives no size): the length is read from a point this far off truck B's pivot,
            across the truck, so the reading gains −e·sin ψ_B. A model of ours.
        rotary_jitter: standard deviation of vibration jitter on each rotary-encoder reading,
            added before quantisation [rad] (not in the paper: a model addition; it dithers
            the 10-bit counts).
        read_skew: how long before the wheel encoders the link encoders are read [s] (not in
            the paper: a model addition); the readings then show the trucks where they were
            ``read_skew`` earlier (linear interpolation within the interval, so at most T_s).
        tyre_compression: how far a compliant tyre flattens over a cable [m] (not in the paper,
            which assumes rigid wheels, §3.1): the wheel centre then climbs only the cable's
            diameter less this, so the cable acts as a thinner one for the crossing geometry
            (``odomgym.sim.cables.bump_extra_rotation``). A model of ours.
        trailer: truck B is an unpowered encoder trailer (Borenstein 1995, §7): its rigid
            tongue of length ``link_length`` is pinned to truck A's centre by one rotary joint,
            whose encoder reads ψ_A; the tongue fixes ψ_B at 0 and the length at
            ``link_length`` (no second rotary encoder, no linear encoder); its free-rolling
            wheels carry encoders. ``link_min``/``link_max`` are then unused.
        name: a label for reports.
    """

    truck_a: RobotSpec
    truck_b: RobotSpec
    link_length: float = 1.0
    link_min: float = 0.9
    link_max: float = 1.1
    sample_period: float = 0.04
    rotary_bits: int = 10
    rotary_bias_a: float = 0.0
    rotary_bias_b: float = 0.0
    linear_resolution: float = 1e-4
    linear_bias: float = 0.0
    linear_eccentricity: float = 0.0
    rotary_jitter: float = 0.0
    read_skew: float = 0.0
    tyre_compression: float = 0.0
    trailer: bool = False
    name: str = "vehicle"

    def __post_init__(self) -> None:
        for key in ("truck_a", "truck_b"):
            truck = getattr(self, key)
            if not isinstance(truck, RobotSpec):
                shown = f" {truck!r}" if isinstance(truck, str) else ""
                raise SpecError(
                    f"{key} must be a RobotSpec (odomgym.PRESETS[name] or load_robot(path)), got "
                    f"{type(truck).__name__}{shown}",
                    field=key,
                )
            if truck.is_skid_steer:
                raise SpecError(
                    f"{key} is a skid-steer robot ({truck.name}); the CLAPPER's trucks are "
                    "differential-drive (Borenstein 1995), and IPEC's model has no apparent track",
                    field=key,
                )
        for key in ("link_length", "link_min", "link_max", "sample_period", "linear_resolution"):
            require_positive(key, getattr(self, key))
        # Ranges a real vehicle lies in; beyond them a value is a typo (degrees for radians,
        # millimetres for metres) or would make a run take forever.
        require_range("sample_period", self.sample_period, 1e-3, 1.0)
        require_range("rotary_bias_a", self.rotary_bias_a, -0.5, 0.5)
        require_range("rotary_bias_b", self.rotary_bias_b, -0.5, 0.5)
        require_range("linear_bias", self.linear_bias, -0.1, 0.1)
        require_range("linear_eccentricity", self.linear_eccentricity, -0.1, 0.1)
        require_range("rotary_jitter", self.rotary_jitter, 0.0, 0.1)
        require_range("read_skew", self.read_skew, 0.0, self.sample_period)
        require_range("tyre_compression", self.tyre_compression, 0.0, 0.05)
        if not self.link_min < self.link_length < self.link_max:
            raise SpecError(
                f"link_length must lie strictly between link_min and link_max, got "
                f"{self.link_min} < {self.link_length} < {self.link_max}",
                field="link_length",
            )
        if self.trailer:
            unused = [
                key
                for key in ("linear_bias", "linear_eccentricity", "rotary_bias_b")
                if getattr(self, key) != 0.0
            ]
            if unused:
                raise SpecError(
                    f"a trailer has no linear encoder and no rotary encoder on truck B: "
                    f"{', '.join(unused)} must be 0",
                    field=unused[0],
                )
        bits = self.rotary_bits
        if isinstance(bits, bool) or not isinstance(bits, int) or not 1 <= bits <= 32:
            raise SpecError(
                f"rotary_bits must be a whole number in [1, 32], got {bits!r}", field="rotary_bits"
            )

    @property
    def rotary_resolution(self) -> float:
        """One count of the rotary encoders, 2π / 2^bits [rad]."""
        return 2.0 * math.pi / float(2**self.rotary_bits)

    @property
    def trucks(self) -> tuple[RobotSpec, RobotSpec]:
        """(truck A, truck B)."""
        return (self.truck_a, self.truck_b)

    # ------------------------------------------------------------------ TOML
    def to_dict(self) -> dict[str, Any]:
        """All fields as a TOML-ready dict; a preset truck is written by its name."""
        out: dict[str, Any] = {}
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if isinstance(value, RobotSpec):
                out[f.name] = value.name if PRESETS.get(value.name) == value else value.to_dict()
            else:
                out[f.name] = value
        return out

    @classmethod
    def from_dict(cls, data: Mapping[str, Any], *, path: Path | None = None) -> VehicleSpec:
        """Build from a mapping (e.g. parsed TOML, flat or under ``[vehicle]``); a truck is a
        robot preset name, a robot ``.toml`` path (relative to the vehicle file) or a table.
        Errors name the field and, for a file, the file and line."""
        refuse_stray_keys(data, "vehicle", path)
        raw = data.get("vehicle", data)
        if not isinstance(raw, Mapping):
            raise SpecError(
                "vehicle must be a table ([vehicle]) of vehicle keys",
                field="vehicle",
                source=str(path) if path else None,
            )
        table = dict(raw)

        def where(key: str) -> str | None:
            return locate_key(path, key) if path else None

        known = {f.name for f in dataclasses.fields(cls)}
        for key in table:
            if key not in known:
                raise SpecError(
                    f"unknown vehicle field {key!r}; known fields: {', '.join(sorted(known))}",
                    field=key,
                    source=where(key),
                )
        for key in ("truck_a", "truck_b"):
            value = table.get(key, "labmate")
            if isinstance(value, Mapping):
                try:
                    table[key] = RobotSpec.from_dict(value)
                except SpecError as exc:
                    # Name the truck, and find the line inside its own [vehicle.TRUCK] table.
                    message = str(exc)
                    prefixed = message.startswith(exc.field) if exc.field else False
                    raise SpecError(
                        f"{key}.{message}" if prefixed else f"{key}: {message}",
                        field=f"{key}.{exc.field}" if exc.field else key,
                        source=_locate_in_table(path, key, exc.field) if path else None,
                    ) from None
            elif isinstance(value, str):
                candidate = Path(value)
                if path is not None and not candidate.is_absolute() and value not in PRESETS:
                    candidate = path.parent / candidate
                if value not in PRESETS and candidate.suffix != ".toml":
                    raise SpecError(
                        f"{key}: unknown robot preset {value!r}; presets: "
                        f"{', '.join(sorted(PRESETS))}, or a robot .toml file",
                        field=key,
                        source=where(key),
                    )
                table[key] = load_robot(value if value in PRESETS else candidate)
            else:
                raise SpecError(
                    f"{key} must be a robot preset name, a robot .toml path or a table",
                    field=key,
                    source=where(key),
                )
        for key, value in table.items():
            if key in ("truck_a", "truck_b"):
                continue
            if key == "name":
                if not isinstance(value, str):
                    raise SpecError("name must be a string", field=key, source=where(key))
                continue
            if key == "trailer":
                if not isinstance(value, bool):
                    raise SpecError("trailer must be true or false", field=key, source=where(key))
                continue
            if key == "rotary_bits":
                continue  # checked whole in __post_init__
            require_finite(key, value, source=where(key))
        try:
            return cls(**table)
        except SpecError as exc:
            raise SpecError(
                str(exc), field=exc.field, source=where(exc.field) if exc.field else None
            ) from None

    def save(self, path: str | Path) -> None:
        """Write the spec as TOML, atomically (temp file, then rename)."""
        import tomli_w

        atomic_write_text(Path(path), tomli_w.dumps({"vehicle": self.to_dict()}))


def _locate_in_table(path: Path, table: str, key: str | None) -> str:
    """``"file:line"`` of ``key`` inside the ``[vehicle.TABLE]`` (or ``[TABLE]``) table, or of
    the table's header; the file alone if neither shows."""
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except OSError:
        return str(path)
    header = re.compile(rf"^\s*\[\s*(?:vehicle\.)?{re.escape(table)}\s*\]")
    start = next((n for n, line in enumerate(lines) if header.match(line)), None)
    if start is None:
        return str(path)
    if key:
        leaf = re.compile(rf"^\s*{re.escape(key.split('.')[-1])}\s*=")
        for n in range(start + 1, len(lines)):
            if lines[n].lstrip().startswith("["):
                break
            if leaf.match(lines[n]):
                return f"{path}:{n + 1}"
    return f"{path}:{start + 1}"


def load_vehicle(spec: str | os.PathLike[str] | VehicleSpec) -> VehicleSpec:
    """Return the preset called ``spec`` (``clapper``) or load a vehicle TOML file (a spec is
    returned as it is; anything else is refused in one line naming its type)."""
    return load_named(
        spec,
        VEHICLES,
        "vehicle",
        lambda text: (
            f"unknown vehicle {text!r}; presets: {', '.join(sorted(VEHICLES))}, or a .toml file"
        ),
        VehicleSpec.from_dict,
    )


def link_readings(
    spec: VehicleSpec, poses: FloatArray, rng: np.random.Generator | None = None
) -> LinkReading:
    """What the internal encoders report for true truck poses (N, 2, 3) [m, m, rad].

    Rotary encoders: ψ + bias (+ jitter, drawn from ``rng``, if the spec has any), rounded to
    the nearest count of 2π/2^bits (an absolute encoder reports the count its code disc
    shows). Linear encoder: the centre distance + bias − eccentricity·sin ψ_B, rounded to its
    resolution. Rounding to the nearest count keeps a zero angle at zero; truncation would add
    half a count to every reading.

    The link's direction and length come from numpy's ``arctan2`` and ``hypot`` (as in
    :func:`~odomgym.vehicle.estimator.link_geometry`; libm's differ from them in the last
    bit), the rest from the compiled :func:`_read_link`: a CLAPPER run reads its encoders every
    control step, where numpy's fifteen calls on one vehicle's arrays were a seventh of it.
    """
    p = check_poses(poses, copy=False)
    dx = p[:, 0, 0] - p[:, 1, 0]
    dy = p[:, 0, 1] - p[:, 1, 1]
    jittered = spec.rotary_jitter > 0.0
    if jittered:
        if rng is None:
            raise ValueError("a vehicle with rotary_jitter needs rng= for its readings")
        jitter = spec.rotary_jitter * rng.standard_normal((p.shape[0], 2))
    else:
        jitter = _NO_JITTER
    psi_read, length_read = _read_link(
        p,
        np.arctan2(dy, dx),
        np.hypot(dx, dy),
        spec.rotary_bias_a,
        spec.rotary_bias_b,
        jitter,
        jittered,
        spec.rotary_resolution,
        spec.trailer,
        spec.link_length,
        spec.linear_bias,
        spec.linear_eccentricity,
        spec.linear_resolution,
    )
    return LinkReading(length=length_read, psi=psi_read)


_NO_JITTER = np.zeros((0, 2))


@kernel
def _read_link(
    poses: FloatArray,
    theta_link: FloatArray,
    true_length: FloatArray,
    bias_a: float,
    bias_b: float,
    jitter: FloatArray,
    jittered: bool,
    rotary_resolution: float,
    trailer: bool,
    link_length: float,
    linear_bias: float,
    eccentricity: float,
    linear_resolution: float,
) -> tuple[FloatArray, FloatArray]:
    """:func:`link_readings` after the link's direction θ_L (N,) and length (N,): ψ = θ − θ_L
    wrapped to [−π, π) as numpy's ``mod`` does (Python's float ``%``), the biases, the jitter
    (``jittered``: ``jitter`` (N, 2) [rad] is added), the rounding to counts (``rint``, numpy's
    ``round`` to 0 decimals), the linear encoder's bias, eccentricity and rounding — element by
    element numpy's operations in numpy's order."""
    n = poses.shape[0]
    psi_read = np.empty((n, 2))
    length_read = np.empty(n)
    q, r = rotary_resolution, linear_resolution
    two_pi = 2.0 * math.pi
    for i in range(n):
        psi_b = 0.0
        for truck in range(2):
            psi = (poses[i, truck, 2] - theta_link[i] + math.pi) % two_pi - math.pi
            if truck == 1:
                psi_b = psi
            shown = psi + (bias_a if truck == 0 else bias_b)
            if jittered:
                shown = shown + jitter[i, truck]
            psi_read[i, truck] = q * np.rint(shown / q)
        if trailer:  # one rotary encoder (ψ_A); the rigid tongue fixes ψ_B = 0 and l
            psi_read[i, 1] = 0.0
            length_read[i] = link_length
            continue
        length = true_length[i] + linear_bias
        if eccentricity:
            length = length - eccentricity * np.sin(psi_b)
        length_read[i] = r * np.rint(length / r)
    return psi_read, length_read


def calibrated(truck: RobotSpec) -> RobotSpec:
    """``truck`` as a well-calibrated one: its odometry believes its true wheelbase and its
    true mean wheel diameter, and the diameter ratio is corrected (the true diameters both set
    to the mean), so no systematic odometry error is left (Borenstein 1995, §6: the CLAPPER
    was "well calibrated")."""
    mean = 0.5 * (truck.true_left_diameter + truck.true_right_diameter)
    return dataclasses.replace(
        truck,
        name=f"{truck.name}-calibrated",
        wheelbase=truck.true_wheelbase,
        wheel_diameter=mean,
        true_left_diameter=mean,
        true_right_diameter=mean,
        source=f"{truck.source}; calibrated: nominal = true, equal diameters",
    )


PAPER_ERRORS: dict[str, float] = {
    "linear_bias": 0.002,
    "rotary_jitter": math.radians(0.1),
    "linear_eccentricity": 0.001,
    "read_skew": 0.004,
}
"""The error sources at the magnitudes the paper gives or, where it gives none, a stated
assumption (``docs/clapper.md``, "Error sources"): link-length bias 2 mm (Borenstein 1995,
§5.2: "on the order of 2 mm"); vibration jitter 0.1° (assumed, under one 0.35° count);
eccentricity 1 mm (named in §5.2 without a size; assumed); read skew 4 ms (a tenth of T_s,
assumed). The rotary biases are left at 0: §5.3 says simple calibration removes them."""


ENCODER_TRAILER = RobotSpec(
    name="encoder-trailer",
    wheel_diameter=0.10,
    wheelbase=0.30,
    ticks_per_rev=2048.0,
    mass=8.0,
    chassis_length=0.30,
    chassis_width=0.35,
    drive_load_fraction=1.0,
    max_wheel_speed=10.0,  # free-rolling: no motor limits its wheels
    max_wheel_accel=100.0,
    source="assumed: Borenstein 1995, §7 gives no geometry (one rotary joint, towed); a "
    "two-wheeled trailer with wheel encoders as in Chong & Kleeman 1997 (Andros)",
)
"""The encoder trailer's body: two free-rolling 100 mm wheels 0.3 m apart, 8 kg (assumed)."""


#: Vehicle presets.
VEHICLES: dict[str, VehicleSpec] = {
    # Borenstein 1995, §2-§3: two LabMate trucks 1 m apart, 10-bit rotary encoders, 0.1 mm
    # linear encoder, 40 ms sampling; the bearing range (±0.1 m) is assumed.
    "clapper": VehicleSpec(
        truck_a=calibrated(PRESETS["labmate"]),
        truck_b=calibrated(PRESETS["labmate"]),
        name="clapper",
    ),
    # The same vehicle with the LabMates as they come (b 340 mm believed, 336.17 mm true;
    # D_R/D_L = 1.00084: Borenstein & Feng 1994, Fig. 6.5).
    "clapper-uncalibrated": VehicleSpec(
        truck_a=PRESETS["labmate"],
        truck_b=PRESETS["labmate"],
        name="clapper-uncalibrated",
    ),
    # Borenstein 1995, §7: a conventional robot (a calibrated LabMate) towing an encoder trailer
    # on a 1 m tongue, one rotary encoder at the hitch (the CLAPPER's 10 bits).
    "trailer": VehicleSpec(
        truck_a=calibrated(PRESETS["labmate"]),
        truck_b=ENCODER_TRAILER,
        trailer=True,
        name="trailer",
    ),
}
