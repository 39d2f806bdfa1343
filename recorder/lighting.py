"""Per-lap lighting (``--lighting-change F``): each lap of the route lit differently.

A real building is not lit the same way on every visit: the sun moves, lamps age or are switched
off, a different shift turns on other lights.  With ``F`` > 0 every lap gets its own
:class:`Lighting`, drawn from ``default_rng((seed, 3))``:

* **intensity**: point and ambient light scaled by ``exp(±F · U(0.3, 0.6))`` (×0.55…×1.8 at
  F = 1), the sign alternating from lap to lap so consecutive laps always differ;
* **colour temperature**: ``4000 K · exp(±F · U(0.2, 0.45))`` (about 2550–3270 K or 4900–6270 K
  at F = 1), again alternating, applied as a tint relative to the default light colour at the same
  luminance;
* **which lights are on**: each ceiling light is off with probability ``0.5 · F`` (at least one
  stays on); an off light neither lights the scene nor glows.

``F = 0`` gives :data:`DEFAULT` for every lap, which the renderer draws exactly as before.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass

import numpy as np

#: Colour temperature the default light colour stands for.
REFERENCE_TEMPERATURE_K = 4000.0
#: The default point-light colour (warm white).
DEFAULT_COLOUR = (1.0, 0.97, 0.9)
INTENSITY_LOG_RANGE = (0.3, 0.6)
TEMPERATURE_LOG_RANGE = (0.2, 0.45)
MAX_OFF_FRACTION = 0.5


@dataclass(frozen=True)
class Lighting:
    """How one lap is lit: a brightness factor, a light colour, and which ceiling lights are on.

    ``lights_on=None`` means all of them.
    """

    intensity: float = 1.0
    temperature_k: float = REFERENCE_TEMPERATURE_K
    colour: tuple[float, float, float] = DEFAULT_COLOUR
    lights_on: tuple[bool, ...] | None = None

    @property
    def is_default(self) -> bool:
        return self == DEFAULT

    def to_dict(self) -> dict:
        doc: dict = {
            "intensity": round(self.intensity, 6),
            "temperature_k": round(self.temperature_k, 1),
            "colour": [round(c, 6) for c in self.colour],
        }
        if self.lights_on is not None:
            doc["lights_off"] = [i for i, on in enumerate(self.lights_on) if not on]
        return doc


DEFAULT = Lighting()


def kelvin_to_rgb(temperature_k: float) -> np.ndarray:
    """Approximate sRGB colour (0…1) of a black body (Tanner Helland's fit, 1000–40000 K)."""
    t = min(max(temperature_k, 1000.0), 40000.0) / 100.0
    r = 255.0 if t <= 66 else 329.698727446 * (t - 60) ** -0.1332047592
    g = (
        99.4708025861 * math.log(t) - 161.1195681661
        if t <= 66
        else 288.1221695283 * (t - 60) ** -0.0755148492
    )
    if t >= 66:
        b = 255.0
    elif t <= 19:
        b = 0.0
    else:
        b = 138.5177312231 * math.log(t - 10) - 305.0447927307
    return np.clip(np.array([r, g, b]), 0.0, 255.0) / 255.0


def _luminance(rgb: np.ndarray) -> float:
    return float(np.dot(rgb, [0.2126, 0.7152, 0.0722]))


def tinted_colour(temperature_k: float) -> tuple[float, float, float]:
    """The default light colour shifted to ``temperature_k``, at the default colour's luminance."""
    base = np.array(DEFAULT_COLOUR)
    colour = base * kelvin_to_rgb(temperature_k) / kelvin_to_rgb(REFERENCE_TEMPERATURE_K)
    colour *= _luminance(base) / _luminance(colour)
    red, green, blue = (float(c) for c in colour)
    return red, green, blue


def lap_lighting(change: float, laps: int, n_lights: int, seed: int) -> tuple[Lighting, ...]:
    """One :class:`Lighting` per lap (see the module docstring); all :data:`DEFAULT` when ``change`` is 0."""
    if change <= 0.0:
        return (DEFAULT,) * laps
    rng = np.random.default_rng([seed, 3])
    intensity_sign = 1.0 if rng.random() < 0.5 else -1.0
    temperature_sign = 1.0 if rng.random() < 0.5 else -1.0
    out = []
    for lap in range(laps):
        alternate = 1.0 if lap % 2 == 0 else -1.0
        log_i = change * rng.uniform(*INTENSITY_LOG_RANGE) * intensity_sign * alternate
        log_t = change * rng.uniform(*TEMPERATURE_LOG_RANGE) * temperature_sign * alternate
        on = rng.random(n_lights) >= MAX_OFF_FRACTION * change
        if n_lights and not on.any():
            on[int(rng.integers(n_lights))] = True
        temperature = REFERENCE_TEMPERATURE_K * math.exp(log_t)
        out.append(
            Lighting(
                intensity=math.exp(log_i),
                temperature_k=temperature,
                colour=tinted_colour(temperature),
                lights_on=tuple(bool(v) for v in on),
            )
        )
    return tuple(out)


def lighting_json(change: float, lightings: tuple[Lighting, ...]) -> str:
    """The per-lap lighting, as stored in the recording's metadata."""
    doc = {"change": change, "laps": [lighting.to_dict() for lighting in lightings]}
    return json.dumps(doc, separators=(",", ":"))
