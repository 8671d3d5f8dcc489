"""Procedural bottles and cans: closed solids of revolution (a depth camera sees their outside only).

Object frame as the mug's: z up, metres, the base at z = 0, the axis on the z axis. Each profile
runs from the bottom pole (on the axis, under the base) out along the underside, up the wall and in
over the top to the top pole, counter-clockwise around the material (`revolve_profile`).

Bottles (water, soda, wine, oil, sauce, beer bottles): 5-10 cm wide, 12-35 cm tall, a straight,
waisted or tapered body; a shoulder from round to long and sloped (wine); a neck 1-10 cm long,
1.8-4 cm wide; a screw cap, or a lip ring around an open mouth; a flat or pushed-up (punt) base.

Cans: "drink" (5.2-6.8 cm wide, 9-17 cm tall: a domed bottom on a narrow ring, the top necked in
under the seam) and "food" (6-10 cm wide, 3.5-18 cm tall, tuna to soup cans: straight, a seam rim
at both ends); the lid sunk below its rim (the countersink).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from ndfa.sim.mesh import Mesh
from ndfa.sim.mug_body import revolve_profile

BOTTLE_BODIES = ("straight", "waisted", "tapered")
BOTTLE_FINISHES = ("screw_cap", "lip")
CAN_KINDS = ("drink", "food")
SEGMENTS = 48  # angular segments, as the mug's body


@dataclass(frozen=True)
class BottleParams:
    body: str = "straight"  # one of BOTTLE_BODIES
    height: float = 0.25  # base to the top of the cap or lip
    radius: float = 0.035  # body radius at the base
    waist: float = 0.0  # fraction of the radius the body narrows at mid-height ("waisted")
    top_ratio: float = 1.0  # body radius under the shoulder over `radius` ("tapered": < 1)
    shoulder_height: float = 0.05  # from the body to the neck
    shoulder_exponent: float = 1.0  # < 1 a round shoulder, > 1 a long concave slope (wine)
    neck_radius: float = 0.013
    neck_length: float = 0.03  # from the shoulder to the cap or lip
    finish: str = "screw_cap"  # one of BOTTLE_FINISHES
    finish_height: float = 0.02  # the cap's or the lip ring's height
    finish_radius: float = 0.015  # the cap's or the lip ring's outer radius
    mouth_radius: float = 0.01  # the open mouth inside the lip ("lip" only)
    mouth_depth: float = 0.01  # how deep the mouth is seen from above ("lip" only)
    bottom_fillet: float = 0.005  # the rounded edge the bottle stands on
    punt: float = 0.0  # how far the centre of the underside is pushed up


@dataclass(frozen=True)
class CanParams:
    kind: str = "drink"  # one of CAN_KINDS
    height: float = 0.115
    radius: float = 0.033  # body radius
    top_radius: float = 0.027  # the seam's radius at the top ("drink": necked in; "food": = radius)
    neck_height: float = 0.012  # height over which the top necks in ("drink" only)
    bottom_height: float = 0.01  # height over which the bottom narrows to its ring ("drink": the dome's shoulder)
    ring_radius: float = 0.025  # the ring the can stands on
    dome: float = 0.01  # how far the centre of the underside is pushed up
    seam_width: float = 0.0015  # the rim's width at the top (and at the bottom of a food can)
    countersink: float = 0.004  # how far the lid lies below the rim


def _plain(params):  # noqa: ANN001, ANN202 - either dataclass above
    """`params` with plain Python floats, not numpy scalars: a readable repr and JSON-ready fields."""
    values = {f.name: getattr(params, f.name) for f in fields(params)}
    return type(params)(**{name: float(v) if isinstance(v, np.floating) else v for name, v in values.items()})


def sample_bottle_params(rng: np.random.Generator) -> BottleParams:
    body = str(rng.choice(BOTTLE_BODIES, p=[0.5, 0.2, 0.3]))
    height = rng.uniform(0.12, 0.35)
    radius = rng.uniform(0.025, min(0.05, height / 3.5))
    finish = str(rng.choice(BOTTLE_FINISHES, p=[0.65, 0.35]))
    neck_radius = rng.uniform(0.009, min(0.02, 0.6 * radius))
    finish_radius = neck_radius + (rng.uniform(0.0015, 0.004) if finish == "screw_cap" else rng.uniform(0.001, 0.0025))
    finish_height = rng.uniform(0.012, 0.028) if finish == "screw_cap" else rng.uniform(0.003, 0.007)
    # The neck and shoulder take at most half the height: the body is the bottle's larger part.
    neck_length = rng.uniform(0.01, min(0.1, 0.3 * height))
    shoulder_height = rng.uniform(0.15, 0.3) * height
    shrink = min(1.0, (0.5 * height - finish_height) / (neck_length + shoulder_height))
    neck_length, shoulder_height = neck_length * shrink, shoulder_height * shrink
    wall = rng.uniform(0.0015, 0.003)
    return _plain(BottleParams(
        body=body, height=height, radius=radius,
        waist=rng.uniform(0.05, 0.15) if body == "waisted" else 0.0,
        top_ratio=rng.uniform(0.75, 0.95) if body == "tapered" else 1.0,
        shoulder_height=shoulder_height, shoulder_exponent=float(np.exp(rng.uniform(np.log(0.4), np.log(2.5)))),
        neck_radius=neck_radius, neck_length=neck_length, finish=finish, finish_height=finish_height,
        finish_radius=finish_radius, mouth_radius=neck_radius - wall,
        mouth_depth=rng.uniform(0.005, 0.015), bottom_fillet=rng.uniform(0.002, 0.008),
        punt=rng.uniform(0.005, min(0.025, 0.1 * height)) if rng.random() < 0.2 else 0.0,
    ))


def bottle_profile(p: BottleParams) -> np.ndarray:
    """Closed (r, z) profile of the bottle, pole to pole (see the module docstring)."""
    shoulder_top = p.height - p.finish_height - p.neck_length
    shoulder_start = shoulder_top - p.shoulder_height

    def body_radius(z: np.ndarray) -> np.ndarray:
        t = np.clip(z / shoulder_start, 0.0, 1.0)
        return p.radius * (1.0 + (p.top_ratio - 1.0) * t - p.waist * np.sin(np.pi * t) ** 2)

    pieces = [np.array([[0.0, p.punt]])]
    ring = p.radius - p.bottom_fillet - 0.003  # the flat ring the bottle stands on starts here
    if p.punt > 0:  # the pushed-up centre, down to the ring
        v = np.linspace(0.0, 1.0, 9)[1:]
        pieces.append(np.c_[ring * np.sin(np.pi / 2 * v), p.punt * np.cos(np.pi / 2 * v)])
    pieces.append(np.array([[p.radius - p.bottom_fillet, 0.0]]))
    angles = np.linspace(-np.pi / 2, 0.0, 6)[1:]
    pieces.append(np.c_[p.radius - p.bottom_fillet + p.bottom_fillet * np.cos(angles),
                        p.bottom_fillet + p.bottom_fillet * np.sin(angles)])
    z = np.linspace(p.bottom_fillet, shoulder_start, 25)[1:]
    pieces.append(np.c_[body_radius(z), z])
    u = np.linspace(0.0, 1.0, 25)[1:]  # the shoulder: vertical where it leaves the body
    under = float(body_radius(np.array([shoulder_start]))[0])
    pieces.append(np.c_[p.neck_radius + (under - p.neck_radius) * np.cos(np.pi / 2 * u) ** p.shoulder_exponent,
                        shoulder_start + u * p.shoulder_height])
    finish_base = p.height - p.finish_height
    pieces.append(np.array([[p.neck_radius, finish_base], [p.finish_radius, finish_base]]))
    edge = min(0.0015, p.finish_height / 3, (p.finish_radius - p.mouth_radius) / 3)
    pieces.append(np.array([[p.finish_radius, p.height - edge], [p.finish_radius - edge, p.height]]))
    if p.finish == "lip":
        pieces.append(np.array([[p.mouth_radius, p.height], [p.mouth_radius, p.height - p.mouth_depth],
                                [0.0, p.height - p.mouth_depth]]))
    else:
        pieces.append(np.array([[0.0, p.height]]))
    return np.concatenate(pieces)


def bottle_parts(params: BottleParams) -> list[Mesh]:
    return [revolve_profile(bottle_profile(params), SEGMENTS)]


def sample_can_params(rng: np.random.Generator) -> CanParams:
    kind = str(rng.choice(CAN_KINDS, p=[0.55, 0.45]))
    if kind == "drink":  # 150 ml slim to 500 ml, and the squat 250 ml cans
        radius = rng.uniform(0.026, 0.034)
        height = rng.uniform(max(0.09, 2.2 * radius), 0.17)
        top = radius * rng.uniform(0.78, 0.9)
        return _plain(CanParams(
            kind=kind, height=height, radius=radius, top_radius=top, neck_height=rng.uniform(0.008, 0.016),
            bottom_height=rng.uniform(0.006, 0.012), ring_radius=radius * rng.uniform(0.65, 0.8),
            dome=rng.uniform(0.006, 0.012), seam_width=rng.uniform(0.001, 0.002), countersink=rng.uniform(0.003, 0.006)))
    radius = rng.uniform(0.03, 0.05)
    height = rng.uniform(0.035, min(0.18, 4.0 * radius))
    return _plain(CanParams(
        kind=kind, height=height, radius=radius, top_radius=radius, neck_height=0.0, bottom_height=0.0,
        ring_radius=radius, dome=rng.uniform(0.002, 0.005), seam_width=rng.uniform(0.0015, 0.0025),
        countersink=rng.uniform(0.002, 0.005)))


def can_profile(p: CanParams) -> np.ndarray:
    """Closed (r, z) profile of the can, pole to pole (see the module docstring)."""
    bead = 0.0008  # the rounding of the seams' edges
    if p.kind == "drink":  # the dome, down to the ring, then out and up to the wall
        v = np.linspace(0.0, 1.0, 9)
        pieces = [np.c_[(p.ring_radius - bead) * np.sin(np.pi / 2 * v), p.dome * np.cos(np.pi / 2 * v)]]
        angles = np.linspace(-np.pi / 2, 0.0, 7)[1:]
        pieces.append(np.c_[p.ring_radius + (p.radius - p.ring_radius) * np.cos(angles),
                            p.bottom_height + p.bottom_height * np.sin(angles)])
    else:  # a sunk bottom inside the seam the can stands on
        inner = p.radius - p.seam_width
        pieces = [np.array([[0.0, p.dome], [inner - bead, p.dome], [inner, 0.0], [p.radius - bead, 0.0],
                            [p.radius, bead]])]
    wall_top = p.height - bead - p.neck_height
    pieces.append(np.array([[p.radius, wall_top]]))
    if p.neck_height > 0:  # the neck: vertical where it leaves the wall and where it meets the seam
        u = np.linspace(0.0, 1.0, 9)[1:]
        pieces.append(np.c_[p.top_radius + (p.radius - p.top_radius) * (1 + np.cos(np.pi * u)) / 2,
                            wall_top + u * p.neck_height])
    inner_top = p.top_radius - p.seam_width
    pieces.append(np.array([[p.top_radius - bead, p.height], [inner_top, p.height],
                            [inner_top - bead, p.height - p.countersink], [0.0, p.height - p.countersink]]))
    return np.concatenate(pieces)


def can_parts(params: CanParams) -> list[Mesh]:
    return [revolve_profile(can_profile(params), SEGMENTS)]
