"""The error model of the phantom experiment: every source of error, its magnitudes and where each number comes from.

Why: the thesis' phantom ended at 8.9 +- 3.3 mm RMS (§5.1, Fig. 16) while its parts measured far better alone; the
error budget (``snreg budget``) and the realistic demo (``snreg demo --errors``) need one description of what errs
and by how much, readable and editable by a research engineer. A model is a YAML file (OpenCV ``FileStorage``, like
the calibration and probe files) with one block per source; each parameter is either a number or a map
``{value, cite}`` whose ``cite`` says where the number comes from (a thesis section, table or figure, or a
measurement of this project with its command). ``resources/errors/ideal.yaml`` is today's demo (only the render's
sensor noise and the SPECT's own counts err), ``resources/errors/thesis.yaml`` the thesis' set-up.

A source's ``scale`` multiplies the error it contributes (1 as measured, 0 off, 0.5 half as large): the "what if"
of ``snreg budget --set tracking=0.5``; ``--set tracking.noise_sigma=3`` changes one parameter.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

from snreg.files import read_storage_with

__all__ = ["SOURCES", "PARAMETERS", "Parameter", "ErrorModel", "load_error_model", "ERRORS_DIR", "NAMED_MODELS"]

ERRORS_DIR = Path(__file__).resolve().parents[2] / "resources" / "errors"
NAMED_MODELS = ("ideal", "thesis")
# the phantom experiment's sources of error, in the order of the data flow
SOURCES = ("calibration", "tracking", "pointing", "imu", "chain", "spect", "tissue", "camera")


@dataclass(frozen=True)
class Parameter:
    """One magnitude of a source: its value in the ideal model, unit, bounds (inclusive) or choices, and meaning."""

    default: float | str
    unit: str
    help: str
    low: float = 0.0
    high: float = float("inf")
    choices: tuple[str, ...] = ()
    integer: bool = False

    def parse(self, text, where: str):
        """The value of ``text`` (a number or a choice) checked against the bounds; ValueError naming ``where``."""
        if self.choices:
            value = str(text).strip()
            if value not in self.choices:
                raise ValueError(f"{where} must be one of {', '.join(self.choices)}, not {value!r}")
            return value
        try:
            value = float(text)
        except (TypeError, ValueError):
            raise ValueError(f"{where} must be a number ({self.unit}), not {text!r}") from None
        if not self.low <= value <= self.high or value != value:
            bounds = f"at least {self.low:g}" if self.high == float("inf") else f"between {self.low:g} and {self.high:g}"
            unit = f" {self.unit}" if self.unit else ""
            raise ValueError(f"{where} must be {bounds}{unit}, not {text}")
        if self.integer:
            if value != int(value):
                raise ValueError(f"{where} must be a whole number, not {text}")
            return int(value)
        return value


def _p(default, unit, text, **kw) -> Parameter:
    return Parameter(default, unit, text, **kw)


PARAMETERS: dict[str, dict[str, Parameter]] = {
    "calibration": {
        "views": _p(30, "views", "checkerboard views calibrated (thesis board: 10x7 inner corners, 10 mm)", low=3,
                    high=200, integer=True),
        "corner_noise_px": _p(0.0, "px", "sd of each detected corner coordinate", high=10.0),
    },
    "tracking": {
        "method": _p("triangulation", "", "the tracker", choices=("triangulation", "sgbm", "width")),
        "noise_sigma": _p(2.0, "grey levels", "sensor noise of the rendered frames", high=50.0),
        "blur_px": _p(0.0, "px", "Gaussian blur (sd) of the rendered frames", high=5.0),
        "frames": _p(3, "frames", "noisy frames tracked per node and draw (their median is the node)", low=1, high=60,
                     integer=True),
        "residual_mm": _p(0.0, "mm", "sd per axis of the tracker's error the renderer does not produce", high=50.0),
    },
    "pointing": {
        "lateral_mm": _p(0.0, "mm", "radius within which the count peak puts the probe's axis beside the node",
                         high=50.0),
        "axial_mm": _p(0.0, "mm", "the node's centre lies up to this far ahead of the tip, along the probe", high=50.0),
    },
    "imu": {
        "gyro_bias_dps": _p(0.0, "deg/s", "gyroscope bias per axis, drawn within +-this", high=5.0),
        "gyro_noise_dps": _p(0.0, "deg/s/sqrt(Hz)", "gyroscope noise density", high=0.1),
        "accel_noise_g": _p(0.0, "g/sqrt(Hz)", "accelerometer noise density", high=0.01),
        "fusion": _p("project", "", "the fusion's bias handling: the app's (start-up average + run-time estimate) or "
                     "imufusion's defaults alone", choices=("project", "imufusion")),
        "node_interval_s": _p(60.0, "s", "time between two stored nodes (the yaw drifts meanwhile)", high=3600.0),
        "turn_error_deg": _p(0.0, "deg", "mean error of a measured camera turn", high=20.0),
        "turn_error_sd_deg": _p(0.0, "deg", "sd of that error", high=20.0),
    },
    "chain": {
        "trocar_camera_sd_mm": _p(0.0, "mm", "error sd of the trocar-camera distance", high=100.0),
        "imu_trocar_sd_mm": _p(0.0, "mm", "error sd of the IMU-trocar distance", high=100.0),
        "imu_camera_deg": _p(0.0, "deg", "angle of the IMU-camera misalignment (axes aligned by eye)", high=45.0),
    },
    "spect": {
        "voxel_mm": _p(4.795, "mm", "voxel size", low=0.5, high=20.0),
        "fwhm_mm": _p(12.0, "mm", "scanner resolution (FWHM of a point source)", low=1.0, high=50.0),
        "peak_counts": _p(2000.0, "counts", "counts of a point source's peak voxel (Poisson noise)", low=10.0,
                          high=1e7),
    },
    "tissue": {
        "per_node_mm": _p(0.0, "mm", "sd per axis of each node's own shift between scan and surgery", high=50.0),
        "setup_tilt_deg": _p(4.0, "deg", "the set-up's tilt beyond the operator's assumed one (rigid)", high=60.0),
        "setup_turn_deg": _p(7.0, "deg", "the set-up's turn the operator's alignment misses (rigid)", high=60.0),
    },
    "camera": {
        "turn_deg": _p(0.0, "deg", "camera turn about the vertical between the left and the right nodes", high=60.0),
        "insertion_sd_mm": _p(0.0, "mm", "sd of the change of the camera's distance from the pivot per pose",
                              high=100.0),
        "insertion": _p("unseen", "", "that change: unseen (the chain keeps its distance, as the thesis) or tracked "
                        "(snreg.odometry measures it, with tracked_sd_mm of error)", choices=("unseen", "tracked")),
        "tracked_sd_mm": _p(0.05, "mm", "sd of the tracked insertion's error per pose", high=50.0),
    },
}


@dataclass(frozen=True)
class ErrorModel:
    """Magnitudes per source (``values[source][parameter]``), their citations, and a scale per source."""

    name: str
    values: dict[str, dict[str, float | str]]
    citations: dict[str, dict[str, str]] = field(default_factory=dict)
    scale: dict[str, float] = field(default_factory=lambda: {s: 1.0 for s in SOURCES})
    path: str = ""

    def __getitem__(self, key: tuple[str, str]):
        source, name = key
        return self.values[source][name]

    def cite(self, source: str, name: str) -> str:
        return self.citations.get(source, {}).get(name, "")

    def with_setting(self, text: str) -> "ErrorModel":
        """This model with ``SOURCE=FACTOR`` (scale the source's error) or ``SOURCE.PARAMETER=VALUE`` applied;
        ValueError in one sentence for an unknown name or a bad value."""
        name, sep, value = text.partition("=")
        name, value = name.strip(), value.strip()
        if not sep or not name or not value:
            raise ValueError(f"--set wants SOURCE=FACTOR or SOURCE.PARAMETER=VALUE, not {text!r}")
        source, dot, parameter = name.partition(".")
        _check_source(source, "--set")
        if not dot:
            factor = Parameter(1.0, "", "", high=100.0).parse(value, f"--set {source} (a factor)")
            return replace(self, scale={**self.scale, source: factor})
        spec = _parameter(source, parameter, "--set")
        values = {s: dict(v) for s, v in self.values.items()}
        values[source][parameter] = spec.parse(value, f"--set {name}")
        citations = {s: dict(c) for s, c in self.citations.items()}
        citations.setdefault(source, {})[parameter] = f"set on the command line (--set {name}={value})"
        return replace(self, values=values, citations=citations)

    def only(self, sources) -> "ErrorModel":
        """This model with every source not in ``sources`` switched off (scale 0); the others keep their scale."""
        keep = set(sources)
        return replace(self, scale={s: (f if s in keep else 0.0) for s, f in self.scale.items()})

    def on(self, source: str) -> float:
        """The scale of ``source`` (0: off)."""
        return float(self.scale.get(source, 0.0))


def load_error_model(name_or_path: str | Path) -> ErrorModel:
    """``"ideal"``, ``"thesis"`` or a YAML file; parameters left out keep their ideal values. ValueError says what is
    wrong (an unknown source or parameter, a value out of bounds, an unreadable file) in one sentence."""
    text = str(name_or_path)
    path = ERRORS_DIR / f"{text}.yaml" if text in NAMED_MODELS else Path(text)
    if not path.exists() and not path.is_symlink():
        raise ValueError(f"{path}: no such error model file; use ideal, thesis or a YAML file like "
                         f"{ERRORS_DIR / 'thesis.yaml'}")
    return read_storage_with(path, "error model", ValueError, lambda fs: _read(fs, path))


def _read(fs, path: Path) -> ErrorModel:
    root = fs.root()
    values = {s: {p: spec.default for p, spec in PARAMETERS[s].items()} for s in SOURCES}
    citations: dict[str, dict[str, str]] = {s: {} for s in SOURCES}
    name = path.stem
    for source in root.keys():
        if source == "name":
            name = root.getNode("name").string().strip() or name
            continue
        _check_source(source, str(path))
        block = root.getNode(source)
        if not block.isMap():
            raise ValueError(f"{path}: {source} must be a block of parameters")
        for parameter in block.keys():
            spec = _parameter(source, parameter, str(path))
            node = block.getNode(parameter)
            cite = ""
            if node.isMap():
                cite = node.getNode("cite").string().strip() if not node.getNode("cite").empty() else ""
                node = node.getNode("value")
                if node.empty():
                    raise ValueError(f"{path}: {source}.{parameter} lacks its value")
            raw = node.string() if node.isString() else node.real()
            values[source][parameter] = spec.parse(raw, f"{path}: {source}.{parameter}")
            citations[source][parameter] = cite
    return ErrorModel(name, values, citations, path=str(path))


def _check_source(source: str, where: str) -> None:
    if source not in SOURCES:
        raise ValueError(f"{where}: unknown error source {source!r}; the sources are {', '.join(SOURCES)}")


def _parameter(source: str, parameter: str, where: str) -> Parameter:
    spec = PARAMETERS[source].get(parameter)
    if spec is None:
        raise ValueError(f"{where}: {source} has no parameter {parameter!r}; its parameters are "
                         f"{', '.join(PARAMETERS[source])}")
    return spec
