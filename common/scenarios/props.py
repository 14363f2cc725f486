"""The objects a street is furnished with, as unions of boxes with one dominant colour each.

Sizes are typical European ones. Colours come from small palettes, so several objects share a
colour and some match what stands behind them (a grey car before a grey wall), which is what
the colour-based clustering has to cope with.
"""

from __future__ import annotations

import numpy as np

from common.scenarios.world import Material, Part, Path, Thing

CAR_COLOURS = (
    (0.70, 0.12, 0.10), (0.12, 0.22, 0.55), (0.82, 0.82, 0.80), (0.55, 0.56, 0.58),
    (0.12, 0.12, 0.13), (0.15, 0.35, 0.20), (0.85, 0.70, 0.15), (0.55, 0.56, 0.58),
)
CLOTHES = (
    (0.15, 0.18, 0.35), (0.60, 0.15, 0.15), (0.25, 0.25, 0.25), (0.80, 0.75, 0.60),
    (0.20, 0.45, 0.25), (0.85, 0.55, 0.15), (0.45, 0.44, 0.42),
)
FACADES = (
    (0.78, 0.70, 0.55), (0.62, 0.30, 0.22), (0.55, 0.55, 0.55), (0.85, 0.84, 0.80), (0.75, 0.58, 0.30),
)
WALLS = ((0.55, 0.55, 0.53), (0.60, 0.32, 0.25), (0.70, 0.66, 0.58))
TYRE = Material((0.08, 0.08, 0.08), amp=0.3, texel=0.01)
SKIN = Material((0.80, 0.62, 0.50), amp=0.15, texel=0.01)
METAL = Material((0.45, 0.47, 0.48), amp=0.2, texel=0.01)


def pick(rng: np.random.Generator, palette: tuple[tuple[float, float, float], ...]) -> tuple[float, float, float]:
    """A palette colour with a little per-object variation."""
    base = np.asarray(palette[int(rng.integers(len(palette)))])
    return tuple(float(c) for c in np.clip(base * rng.uniform(0.92, 1.08), 0.0, 1.0))  # type: ignore[return-value]


def car(oid: int, path: Path, rgb: tuple[float, float, float]) -> Thing:
    paint = Material(rgb, amp=0.18, texel=0.015)
    glass = Material(tuple(0.5 * c + 0.06 for c in rgb), amp=0.2, texel=0.015)  # type: ignore[arg-type]
    parts = (
        Part((0.0, 0.0, 0.575), (4.3, 1.8, 0.65), paint),
        Part((-0.2, 0.0, 1.175), (2.4, 1.6, 0.55), glass),
        Part((1.35, 0.0, 0.125), (0.6, 1.7, 0.25), TYRE),
        Part((-1.35, 0.0, 0.125), (0.6, 1.7, 0.25), TYRE),
    )
    return Thing(oid, "car", parts, (4.3, 1.8, 1.45), path)


def truck(oid: int, path: Path, rgb: tuple[float, float, float]) -> Thing:
    body = Material(rgb, amp=0.2, texel=0.02)
    cab = Material(tuple(0.8 * c for c in rgb), amp=0.2, texel=0.02)  # type: ignore[arg-type]
    parts = (
        Part((-1.1, 0.0, 2.0), (8.0, 2.5, 2.8), body),
        Part((3.95, 0.0, 1.8), (2.1, 2.45, 2.4), cab),
        Part((3.5, 0.0, 0.3), (1.0, 2.3, 0.6), TYRE),
        Part((-3.5, 0.0, 0.3), (2.2, 2.3, 0.6), TYRE),
    )
    return Thing(oid, "truck", parts, (10.0, 2.5, 3.4), path)


def pedestrian(oid: int, path: Path, rgb: tuple[float, float, float], legs: tuple[float, float, float]) -> Thing:
    parts = (
        Part((0.0, 0.0, 0.45), (0.3, 0.4, 0.9), Material(legs, amp=0.2, texel=0.01)),
        Part((0.0, 0.0, 1.22), (0.32, 0.52, 0.64), Material(rgb, amp=0.2, texel=0.01)),
        Part((0.0, 0.0, 1.64), (0.22, 0.2, 0.2), SKIN),
    )
    return Thing(oid, "pedestrian", parts, (0.32, 0.52, 1.74), path)


def cyclist(oid: int, path: Path, rgb: tuple[float, float, float]) -> Thing:
    parts = (
        Part((0.0, 0.0, 0.45), (1.7, 0.12, 0.9), METAL),
        Part((-0.1, 0.0, 1.3), (0.45, 0.5, 0.8), Material(rgb, amp=0.2, texel=0.01)),
    )
    return Thing(oid, "cyclist", parts, (1.7, 0.5, 1.7), path)


def box(oid: int, cls: str, path: Path, size: tuple[float, float, float], rgb: tuple[float, float, float],
        amp: float = 0.3, texel: float = 0.03) -> Thing:
    """Anything that is one box: a building, wall, kiosk, bin, pole."""
    part = Part((0.0, 0.0, size[2] / 2), size, Material(rgb, amp=amp, texel=texel))
    return Thing(oid, cls, (part,), size, path)


def gantry(oid: int, path: Path, span: float, clearance: float, rgb: tuple[float, float, float]) -> Thing:
    """A height barrier across the road: two posts and a beam overhead (free space beneath)."""
    mat = Material(rgb, amp=0.25, texel=0.01)
    top = clearance + 0.4
    parts = (
        Part((0.0, -span / 2, top / 2), (0.25, 0.25, top), mat),
        Part((0.0, span / 2, top / 2), (0.25, 0.25, top), mat),
        Part((0.0, 0.0, clearance + 0.2), (0.3, span, 0.4), mat),
    )
    return Thing(oid, "barrier", parts, (0.3, span + 0.25, top), path)


def cantilever_sign(oid: int, path: Path, reach: float, rgb: tuple[float, float, float]) -> Thing:
    """A sign on a pole at the kerb whose board hangs over the lane (pole at local y = -reach/2)."""
    pole = Material((0.5, 0.52, 0.5), amp=0.2, texel=0.01)
    board = Material(rgb, amp=0.25, texel=0.01)
    half = reach / 2
    parts = (
        Part((0.0, -half, 1.8), (0.2, 0.2, 3.6), pole),
        Part((0.0, 0.0, 3.5), (0.15, reach, 0.15), pole),
        Part((0.0, half - 1.4, 2.9), (0.12, 2.6, 1.0), board),
    )
    return Thing(oid, "sign", parts, (0.2, reach, 3.6), path)


def u_fence(oid: int, path: Path, length: float, width: float, rgb: tuple[float, float, float]) -> Thing:
    """A concave obstacle: three fence panels, open towards negative local x."""
    mat = Material(rgb, amp=0.3, texel=0.01)
    h = 1.1
    parts = (
        Part((0.0, -width / 2, h / 2), (length, 0.08, h), mat),
        Part((0.0, width / 2, h / 2), (length, 0.08, h), mat),
        Part((length / 2, 0.0, h / 2), (0.08, width, h), mat),
    )
    return Thing(oid, "fence", parts, (length + 0.08, width + 0.08, h), path)
