"""The recorder's configuration: one frozen dataclass, validated in one place.

Kept free of heavy imports (no numpy, pyrender, cv2) so the CLI can build it while ``aslam --help``
stays instant.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field, fields
from enum import StrEnum
from pathlib import Path
from typing import Any

from aslam.core.errors import ConfigError
from aslam.data_formats.camera import DEFAULT_FOV_DEG, fov_option_problem

DEFAULT_SIZE = (320, 240)
DEFAULT_CAMERA_HEIGHT_M = 1.2
NEAR_PLANE_M = 0.05
"""The renderer's near clipping plane: nearer surfaces are not drawn."""
MIN_CAMERA_HEIGHT_M = 2 * NEAR_PLANE_M
"""Lower, the floor under the camera is clipped: the lower part of every image black (half of it
at a micrometre)."""
GENERATED_CEILING_M = 2.5
"""The ceiling of a generated world; the camera stays 0.1 m below it."""
MAX_SIZE_PX = 4096
MAX_FPS = 120.0


@dataclass(frozen=True)
class CameraSpec:
    """Pinhole camera: image size, horizontal field of view, lens height above the floor."""

    width_px: int = DEFAULT_SIZE[0]
    height_px: int = DEFAULT_SIZE[1]
    fov_deg: float = DEFAULT_FOV_DEG
    height_m: float = DEFAULT_CAMERA_HEIGHT_M

    @property
    def yfov_rad(self) -> float:
        """Vertical field of view of the same pinhole (square pixels)."""
        return 2.0 * math.atan(math.tan(math.radians(self.fov_deg) / 2.0) * self.height_px / self.width_px)


class NoiseModel(StrEnum):
    """How the true path and the odometry relate (see :mod:`aslam.recorder.noise`)."""

    DEFAULT = "default"  # truth = commanded route + jitter/wander; odometry = noisy true actions
    PAPER = "paper"  # truth = noisy executed actions, accumulated; odometry = the commanded actions


#: ``--jitter-m``/``--jitter-deg`` when not given: the default model keeps two visits of a place
#: apart by a little; the paper's model has no jitter (its error is in the executed actions).
DEFAULT_JITTER = {NoiseModel.DEFAULT: (0.05, 1.5), NoiseModel.PAPER: (0.0, 0.0)}


MAX_OFFSET_SIGMA_M = 10.0
"""σ of a true pose's offset from the route. The camera is always held in free space, so offsets
of metres already press it against the walls; a σ of 1e300 was recorded in the metadata while
what was rendered moved 0.7 m."""
MAX_ANGLE_SIGMA_DEG = 180.0
MAX_WANDER_LENGTH_M = 1000.0


@dataclass(frozen=True)
class NoiseParams:
    """Parameters of :mod:`aslam.recorder.noise` (see its docstring for why the model is split)."""

    noise: float = 0.03  # relative σ of each action's distance and turn angle (the paper's 3 %)
    drift_deg_per_m: float = 0.5  # σ of the heading drift per metre driven
    jitter_m: float = 0.05  # σ of the true x and y around the commanded pose (not accumulated)
    jitter_deg: float = 1.5  # σ of the true yaw around the commanded yaw (not accumulated)
    wander_m: float = 0.0  # σ of a smooth offset of the true x and y, correlated along the route
    wander_deg: float = 0.0  # σ of a smooth true heading error, correlated along the route
    wander_length_m: float = 3.0  # correlation length of the wander along the route
    model: NoiseModel = NoiseModel.DEFAULT

    def __post_init__(self) -> None:
        if not isinstance(self.model, NoiseModel) and self.model in set(NoiseModel):
            object.__setattr__(self, "model", NoiseModel(self.model))  # "paper" → NoiseModel.PAPER

    @classmethod
    def of_model(
        cls,
        model: NoiseModel | str = NoiseModel.DEFAULT,
        *,
        jitter_m: float | None = None,
        jitter_deg: float | None = None,
        **rest: Any,
    ) -> NoiseParams:
        """The noise of ``model`` with the jitter it has when not given (``DEFAULT_JITTER``): one
        rule for ``aslam record``'s options and a sweep file's ``[[render]]`` tables."""
        defaults = DEFAULT_JITTER.get(NoiseModel(model) if model in set(NoiseModel) else NoiseModel.DEFAULT)
        assert defaults is not None
        return cls(
            jitter_m=defaults[0] if jitter_m is None else jitter_m,
            jitter_deg=defaults[1] if jitter_deg is None else jitter_deg,
            model=model,  # type: ignore[arg-type]  # a bad name is reported by problems()
            **rest,
        )

    def problems(self) -> list[str]:
        out = []
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name == "model":
                if not isinstance(value, NoiseModel):
                    out.append(f"--noise-model must be one of {', '.join(m.value for m in NoiseModel)}")
                continue
            if not math.isfinite(value) or value < 0:
                out.append(f"--{f.name.replace('_', '-')} must be a finite number ≥ 0, got {value}")
        for name, limit, unit in (
            ("jitter_m", MAX_OFFSET_SIGMA_M, "m"),
            ("wander_m", MAX_OFFSET_SIGMA_M, "m"),
            ("jitter_deg", MAX_ANGLE_SIGMA_DEG, "°"),
            ("wander_deg", MAX_ANGLE_SIGMA_DEG, "°"),
            ("drift_deg_per_m", MAX_ANGLE_SIGMA_DEG, "° per m"),
            ("wander_length_m", MAX_WANDER_LENGTH_M, "m"),
        ):
            value = getattr(self, name)
            if math.isfinite(value) and value > limit:  # the metadata would record what was not rendered
                out.append(f"--{name.replace('_', '-')} must be at most {limit:g} {unit}, got {value:g}")
        if math.isfinite(self.noise) and self.noise >= 1:
            out.append(f"--noise is a relative error and must be < 1, got {self.noise}")
        if math.isfinite(self.wander_length_m) and self.wander_length_m < 0.1:
            out.append(f"--wander-length-m must be at least 0.1 m, got {self.wander_length_m}")
        return out


@dataclass(frozen=True)
class RecordConfig:
    """Everything that decides a recording's content; the same config gives byte-identical files.

    ``laps=None`` means the default: 2 for a preset route (a first visit, then revisits), 1 for a
    route file.  ``fps=None`` renders one image per action (plus the initial one); ``fps=F``
    renders ``round(F)`` images per action (each action takes 1 s).  ``jpeg_quality=None`` writes PNG.
    ``lighting_change`` (0…1) relights every lap differently; ``odometry_reset_at=K`` restarts the
    odometry from zero at keyframe K.
    """

    route: str = "paper"
    laps: int | None = None
    seed: int = 0
    noise: NoiseParams = field(default_factory=NoiseParams)
    aliasing: float = 0.0
    lighting_change: float = 0.0
    odometry_reset_at: int | None = None
    world: Path | None = None
    camera: CameraSpec = field(default_factory=CameraSpec)
    fps: float | None = None
    jpeg_quality: int | None = None
    contact_sheet: Path | None = None

    @classmethod
    def from_options(
        cls,
        route: str,
        *,
        laps: int | None = None,
        seed: int = 0,
        noise_model: NoiseModel | str = NoiseModel.DEFAULT,
        noise: float = NoiseParams.noise,
        drift_deg_per_m: float = NoiseParams.drift_deg_per_m,
        jitter_m: float | None = None,
        jitter_deg: float | None = None,
        wander_m: float = NoiseParams.wander_m,
        wander_deg: float = NoiseParams.wander_deg,
        wander_length_m: float = NoiseParams.wander_length_m,
        aliasing: float = 0.0,
        lighting_change: float = 0.0,
        odometry_reset_at: int | None = None,
        world: Path | None = None,
        width_px: int = CameraSpec.width_px,
        height_px: int = CameraSpec.height_px,
        fov_deg: float = CameraSpec.fov_deg,
        camera_height_m: float = CameraSpec.height_m,
        fps: float | None = None,
        jpeg_quality: int | None = None,
        contact_sheet: Path | None = None,
    ) -> RecordConfig:
        """The config of ``aslam record``'s options, named as they are (a sweep file's ``[[render]]``
        keys too): one way from the flat options to the nested config. Numbers a TOML file may
        spell as integers are taken as the floats they stand for; jitter left None is the noise
        model's own (:meth:`NoiseParams.of_model`)."""

        def real(value: float | None) -> float | None:
            return None if value is None else float(value)

        return cls(
            route=route,
            laps=laps,
            seed=seed,
            noise=NoiseParams.of_model(
                noise_model,
                noise=float(noise),
                drift_deg_per_m=float(drift_deg_per_m),
                jitter_m=real(jitter_m),
                jitter_deg=real(jitter_deg),
                wander_m=float(wander_m),
                wander_deg=float(wander_deg),
                wander_length_m=float(wander_length_m),
            ),
            aliasing=float(aliasing),
            lighting_change=float(lighting_change),
            odometry_reset_at=odometry_reset_at,
            world=world,
            camera=CameraSpec(width_px, height_px, fov_deg=float(fov_deg), height_m=float(camera_height_m)),
            fps=real(fps),
            jpeg_quality=jpeg_quality,
            contact_sheet=contact_sheet,
        )

    @property
    def frames_per_action(self) -> int:
        """``fps`` to the nearest whole number, halves up (``round`` took 2.5 to 2 and 3.5 to 4)."""
        return 1 if self.fps is None else max(1, math.floor(self.fps + 0.5))

    def problems(self) -> list[str]:
        """Every unusable value, each as a message naming its option (empty when all is well)."""
        out = []
        if self.laps is not None and self.laps < 1:
            out.append(f"--laps must be at least 1, got {self.laps}")
        if self.seed < 0:
            out.append(f"--seed must be ≥ 0, got {self.seed}")
        out.extend(self.noise.problems())
        if not (math.isfinite(self.aliasing) and 0.0 <= self.aliasing <= 1.0):
            out.append(f"--aliasing must be between 0 and 1, got {self.aliasing}")
        if self.world is not None and self.aliasing != 0.0:
            out.append("--aliasing chooses a generated world's surfaces; a --world scene file has its own")
        if not (math.isfinite(self.lighting_change) and 0.0 <= self.lighting_change <= 1.0):
            out.append(f"--lighting-change must be between 0 and 1, got {self.lighting_change}")
        if self.odometry_reset_at is not None and self.odometry_reset_at < 0:
            out.append(f"--odometry-reset-at must be a keyframe index ≥ 0, got {self.odometry_reset_at}")
        cam = self.camera
        if (problem := fov_option_problem(cam.fov_deg)) is not None:
            out.append(problem)
        from aslam.data_formats.images import MAX_PIXELS  # here: it imports OpenCV (0.1 s of --help)

        if not (8 <= cam.width_px <= MAX_SIZE_PX and 8 <= cam.height_px <= MAX_SIZE_PX):
            out.append(
                f"--size must be between 8x8 and {MAX_SIZE_PX}x{MAX_SIZE_PX}, "
                f"got {cam.width_px}x{cam.height_px}"
            )
        elif cam.width_px * cam.height_px > MAX_PIXELS:  # a recording `info` and `estimate` refuse
            out.append(
                f"--size {cam.width_px}x{cam.height_px} is {cam.width_px * cam.height_px:,} pixels;"
                f" at most {MAX_PIXELS:,} (2048x2048), the largest image aslam reads"
            )
        if not (math.isfinite(cam.height_m) and cam.height_m >= MIN_CAMERA_HEIGHT_M):
            out.append(
                f"--camera-height-m must be at least {MIN_CAMERA_HEIGHT_M:g} m (the renderer draws"
                f" nothing nearer than {NEAR_PLANE_M:g} m: the floor under a lower camera is black),"
                f" got {cam.height_m}"
            )
        elif self.world is None and cam.height_m >= GENERATED_CEILING_M - 0.1:
            out.append(
                f"--camera-height-m must be below {GENERATED_CEILING_M - 0.1:g} m in a generated world "
                f"(ceilings are {GENERATED_CEILING_M:g} m), got {cam.height_m}"
            )
        if self.fps is not None and not (math.isfinite(self.fps) and 1.0 <= self.fps <= MAX_FPS):
            out.append(f"--fps must be between 1 and {MAX_FPS:g} frames per second, got {self.fps}")
        if self.jpeg_quality is not None and not 1 <= self.jpeg_quality <= 100:
            out.append(f"--jpeg-quality must be between 1 and 100, got {self.jpeg_quality}")
        return out

    def validate(self) -> None:
        """Raise :class:`ConfigError` with the first problem (and how many more there are)."""
        problems = self.problems()
        if problems:
            more = f" (and {len(problems) - 1} more problem(s))" if len(problems) > 1 else ""
            raise ConfigError(problems[0] + more)


_SIZE = re.compile(r"^\s*(\d{1,9})\s*[xX×]\s*(\d{1,9})\s*$", re.ASCII)  # not another script's digits


def parse_size(text: str) -> tuple[int, int]:
    """``"320x240"`` → ``(320, 240)``; :class:`ConfigError` for anything else."""
    match = _SIZE.match(text)
    if not match:
        raise ConfigError(f"--size must look like WIDTHxHEIGHT (e.g. 320x240), got {text!r}")
    return int(match.group(1)), int(match.group(2))
