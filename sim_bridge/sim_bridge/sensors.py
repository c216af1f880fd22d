"""LiDAR sensor models from their datasheets: beam elevations, firings per revolution, range, noise, mounts.

Pure data: `LidarConfig` (scenario.py) names a model and may override any number; `SensorSpec` is the effective
sensor the ray caster builds its beams from.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

NOMINAL_RATE_HZ = 10.0


@dataclass(frozen=True)
class Mount:
    """Where one sensor of a rig sits in the rig's frame (`lidar`): position (m) and roll, pitch, yaw (degrees)."""

    position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rotation: tuple[float, float, float] = (0.0, 0.0, 0.0)

    def matrix(self) -> np.ndarray:
        """rig <- sensor (4, 4)."""
        roll, pitch, yaw = np.radians(self.rotation)
        cr, sr, cp, sp, cy, sy = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch), np.cos(yaw), np.sin(yaw)
        rz = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
        ry = np.array([[cp, 0.0, sp], [0.0, 1.0, 0.0], [-sp, 0.0, cp]])
        rx = np.array([[1.0, 0.0, 0.0], [0.0, cr, -sr], [0.0, sr, cr]])
        matrix = np.eye(4)
        matrix[:3, :3] = rz @ ry @ rx
        matrix[:3, 3] = self.position
        return matrix


@dataclass(frozen=True)
class SensorModel:
    """A spinning LiDAR (or a rig of identical ones) as its datasheet describes it."""

    name: str
    description: str
    elevations: tuple[float, ...]  # beam elevations in degrees, lowest first (the ring order)
    columns_10hz: int  # firings of each beam per revolution at 10 Hz
    fixed_columns: bool  # the columns are a mode (Ouster), not firings per second divided by the rate (Velodyne)
    rates_hz: tuple[float, ...]  # allowed rotation rates: (low, high) range, or the discrete modes
    rate_range: bool  # rates_hz is a (low, high) range
    min_range: float
    max_range: float
    range_noise: float  # standard deviation of the range (m)
    divergence_mrad: float  # horizontal beam divergence: the footprint is this wide per metre of range
    mounts: tuple[Mount, ...] = (Mount(),)

    def columns_at(self, rate_hz: float) -> int:
        """Firings per beam and revolution at a rotation rate."""
        if self.fixed_columns:
            return self.columns_10hz
        return max(16, int(round(self.columns_10hz * NOMINAL_RATE_HZ / rate_hz)))

    def allows_rate(self, rate_hz: float) -> bool:
        """Whether the sensor spins at this rate."""
        if self.rate_range:
            return self.rates_hz[0] - 1e-9 <= rate_hz <= self.rates_hz[1] + 1e-9
        return any(abs(rate_hz - rate) < 1e-9 for rate in self.rates_hz)

    def rates_text(self) -> str:
        """The allowed rates, for messages."""
        if self.rate_range:
            return f"{self.rates_hz[0]:g} to {self.rates_hz[1]:g} Hz"
        return " or ".join(f"{rate:g}" for rate in self.rates_hz) + " Hz"


# VLP-32C: the datasheet's 32 elevations (degrees), sorted; dense around the horizon, sparse below and above.
VLP32C_ELEVATIONS = (
    -25.0, -15.639, -11.31, -8.843, -7.254, -6.148, -5.333, -4.667, -4.0, -3.667, -3.333, -3.0, -2.667, -2.333, -2.0,
    -1.667, -1.333, -1.0, -0.667, -0.333, 0.0, 0.333, 0.667, 1.0, 1.333, 1.667, 2.333, 3.333, 4.667, 7.0, 10.333, 15.0,
)  # fmt: skip

VELODYNE_RATES = (5.0, 20.0)

SENSOR_MODELS: dict[str, SensorModel] = {
    model.name: model
    for model in (
        SensorModel(
            "hdl64e",
            "Velodyne HDL-64E: 64 beams evenly from -24.9 to +2 deg (0.43 deg apart); 1024 firings per beam at 10 Hz "
            "(the datasheet's S3 fires ~2083: -p lidar.columns:=2083); 100 m; range sigma 1 cm; ~2 mrad divergence",
            tuple(np.linspace(-24.9, 2.0, 64).tolist()), 1024, False, VELODYNE_RATES, True, 1.0, 100.0, 0.01, 2.0,
        ),
        SensorModel(
            "vlp16",
            "Velodyne VLP-16 (Puck): 16 beams from -15 to +15 deg every 2 deg; 0.2 deg azimuth at 10 Hz (1800 "
            "firings); 100 m; +-3 cm typical accuracy (sigma 1.5 cm); 3 mrad horizontal divergence",
            tuple(float(e) for e in range(-15, 16, 2)), 1800, False, VELODYNE_RATES, True, 1.0, 100.0, 0.015, 3.0,
        ),
        SensorModel(
            "vlp32c",
            "Velodyne VLP-32C (Ultra Puck): 32 beams from -25 to +15 deg, 0.33 deg apart around the horizon; 0.2 deg "
            "azimuth at 10 Hz (1800 firings); 200 m; +-3 cm typical accuracy (sigma 1.5 cm); 3 mrad horizontal "
            "divergence",
            VLP32C_ELEVATIONS, 1800, False, VELODYNE_RATES, True, 1.0, 200.0, 0.015, 3.0,
        ),
        SensorModel(
            "os1_128",
            "Ouster OS1-128 (gen 2): 128 beams evenly over 45 deg (-22.5 to +22.5, 0.35 deg apart); 1024 columns at 10 "
            "or 20 Hz; 0.8 to 120 m; range sigma 2 cm (datasheet: 1.5 cm at SNR > 250, 3 cm at SNR 100); 0.18 deg "
            "(3.1 mrad) divergence",
            tuple(np.linspace(-22.5, 22.5, 128).tolist()), 1024, True, (10.0, 20.0), False, 0.8, 120.0, 0.02, 3.14,
        ),
        SensorModel(
            "roof_2x32",
            "Roof rig of two VLP-32C stacked 0.2 m apart, the lower one upside down (as on Argoverse's vehicles): one "
            "merged cloud in the rig frame, ring = beam of its own sensor, field `sensor` = 0 upper, 1 lower; 50 deg "
            "vertical field of view together, 30 deg of it seen by both",
            VLP32C_ELEVATIONS, 1800, False, VELODYNE_RATES, True, 1.0, 200.0, 0.015, 3.0,
            (Mount((0.0, 0.0, 0.1)), Mount((0.0, 0.0, -0.1), (180.0, 0.0, 0.0))),
        ),
    )
}


@dataclass(frozen=True)
class SensorSpec:
    """The effective sensor of a scenario: the model's datasheet values with the scenario's overrides applied."""

    model: str
    elevations: np.ndarray  # (beams,) degrees, lowest first; every sensor of a rig has the same table
    columns: int
    rate_hz: float
    min_range: float
    max_range: float
    range_noise: float
    dropout: float
    mixed_points: float
    divergence_mrad: float
    mounts: tuple[Mount, ...]
    rolling_shutter: bool = False  # columns fire across the period (see sweep.py), not all at the stamp

    @property
    def beams(self) -> int:
        """Beams of each sensor."""
        return len(self.elevations)

    @property
    def sensors(self) -> int:
        """Sensors in the rig (1 for a single LiDAR)."""
        return len(self.mounts)

    @property
    def period(self) -> float:
        """Seconds per revolution."""
        return 1.0 / self.rate_hz

    @property
    def straddle_share(self) -> float:
        """Chance that a beam next to a depth edge has the edge inside its footprint: half the footprint's width over
        the azimuth step, on either side of the beam (the edge lies anywhere between two columns)."""
        return min(1.0, self.divergence_mrad * 1e-3 / 2 / (2 * np.pi / self.columns))

    def column_times(self) -> np.ndarray:
        """(columns,) firing time of each column, s relative to the stamp: all 0 for an instant sweep; else clockwise
        from behind (as Velodyne and Ouster spin, KITTI's seam), one column every period / columns, the last at 0."""
        columns = self.columns
        if not self.rolling_shutter:
            return np.zeros(columns)
        order = (columns // 2 - np.arange(columns)) % columns  # column c looks at azimuth 2 pi c / columns
        return (order - (columns - 1)) * (self.period / columns)

    @property
    def rays(self) -> int:
        """Rays cast per sweep, all sensors together."""
        return self.sensors * self.beams * self.columns

    def summary(self) -> dict[str, object]:
        """The effective numbers, for result files and dataset descriptions."""
        return {
            "model": self.model, "sensors": self.sensors, "beams": self.beams, "columns": self.columns,
            "rate_hz": self.rate_hz, "elevation_min_deg": float(self.elevations[0]),
            "elevation_max_deg": float(self.elevations[-1]), "min_range": self.min_range, "max_range": self.max_range,
            "range_noise": self.range_noise, "dropout": self.dropout, "mixed_points": self.mixed_points,
            "divergence_mrad": self.divergence_mrad, "edge_straddle_share": self.straddle_share,
            "rolling_shutter": self.rolling_shutter,
            "mounts": [{"position": list(m.position), "rotation_deg": list(m.rotation)} for m in self.mounts],
        }  # fmt: skip


def sensor_names() -> list[str]:
    """Names of the sensor models."""
    return list(SENSOR_MODELS)


__all__ = ["Mount", "SensorModel", "SensorSpec", "SENSOR_MODELS", "VLP32C_ELEVATIONS", "sensor_names"]
