"""Typed experiment configuration, loaded once from YAML into frozen dataclasses.

Every section is a frozen dataclass; the loader maps YAML mappings onto them by
field name. Unknown keys, wrong types and invalid values are
:class:`~meshsom.errors.ConfigError` naming the file and the key path
(``som.epochs``), what was received and what was expected.
"""

from __future__ import annotations

import dataclasses
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from meshsom.errors import ConfigError
from meshsom.generate import GeneratorParams
from meshsom.io import ReaderOptions
from meshsom.store import DEFAULT_CHUNK_ROWS


def _preprocess_params_type():
    from meshsom.preprocess import PreprocessParams

    return PreprocessParams


@dataclass(frozen=True)
class CorpusConfig:
    """Where the meshes come from: files and folders, and/or the generator.

    Attributes
    ----------
    paths : tuple of str
        Files or folders, relative to the working directory.
    generator : GeneratorParams or None
        A synthetic corpus added to (or instead of) ``paths``.
    reader : ReaderOptions
    """

    paths: tuple[str, ...] = ()
    generator: GeneratorParams | None = None
    reader: ReaderOptions = ReaderOptions()

    def __post_init__(self):
        if not self.paths and self.generator is None:
            raise ValueError("give at least one of corpus.paths or corpus.generator")


@dataclass(frozen=True)
class EncodingConfig:
    """Which ring levels are encoded, and how they are scaled for training.

    Attributes
    ----------
    levels : tuple of int
        Ring levels to encode (1..8).
    scaling : str
        ``standard`` (default): z-scores per component type, mean and standard deviation over the
        corpus (u: root mean square). ``robust``: centre = median, scale = interquartile range /
        1.349 (the standard deviation of a normal distribution with that IQR; u: centre 0, scale
        from the IQR of u and -u), then clipped to ``+-robust_clip``: a few extreme folds (a
        centimetre edge beside a 30 m wall, v in the thousands) neither stretch the scale of the
        others nor get map units of their own. See :mod:`meshsom.standardize`.
    robust_clip : float
        Largest absolute robust score (in robust standard deviations) under ``scaling: robust``.
    """

    levels: tuple[int, ...] = (1, 2, 3)
    scaling: str = "standard"
    robust_clip: float = 5.0

    def __post_init__(self):
        from meshsom.standardize import SCALINGS

        if self.scaling not in SCALINGS:
            raise ValueError(f"scaling must be one of {sorted(SCALINGS)}, received {self.scaling!r}")
        if not (isinstance(self.robust_clip, (int, float)) and 0 < self.robust_clip < float("inf")):
            raise ValueError(f"robust_clip must be a finite number > 0, received {self.robust_clip!r}")
        if not self.levels:
            raise ValueError("levels must name at least one level")
        for lv in self.levels:
            if not 1 <= lv <= 8:
                raise ValueError(f"levels must lie in 1..8, received {lv}")


@dataclass(frozen=True)
class StoreConfig:
    """The output zarr store.

    Attributes
    ----------
    path : str
    chunk_rows : int
        Rows per chunk of the per-face arrays.
    """

    path: str = "out/meshsom.zarr"
    chunk_rows: int = DEFAULT_CHUNK_ROWS

    def __post_init__(self):
        if self.chunk_rows < 1:
            raise ValueError(f"chunk_rows must be >= 1, received {self.chunk_rows}")


KERNELS = ("default", "bmuofn")
TOPOLOGIES = ("toroidal", "planar")
INITS = ("random", "pca")
TRAININGS = ("batch", "online")
BACKENDS = ("auto", "numpy", "opencl")
#: OpenCL kernel layouts (keys of meshsom.bmu_opencl.DEFAULT_PARAMS; kept here so configs load without pyopencl).
LAYOUTS = ("cpu", "cpu-narrow", "gpu", "tiled")


def parse_layouts(text: str) -> tuple[str, ...]:
    """A comma-separated list of OpenCL kernel layouts, in order ("tiled", "cpu,cpu-narrow,tiled").

    Raises
    ------
    ValueError
        An empty list or an unknown name (the message lists the known ones).
    """
    names = tuple(n.strip() for n in str(text).split(",") if n.strip())
    unknown = [n for n in names if n not in LAYOUTS]
    if not names or unknown:
        raise ValueError(f"layout must be one or more of {', '.join(LAYOUTS)}, comma-separated; received {text!r}")
    return names


@dataclass(frozen=True)
class TrainSpec:
    """One triangle map to train: a ring level and a BMU kernel.

    Attributes
    ----------
    level : int
    kernel : str
        "default" (one variation, the raw vertex order: the paper's level 1*)
        or "bmuofn" (the best of the level's variations).
    """

    level: int
    kernel: str = "bmuofn"

    def __post_init__(self):
        if not 1 <= self.level <= 8:
            raise ValueError(f"level must lie in 1..8, received {self.level}")
        if self.kernel not in KERNELS:
            raise ValueError(f"kernel must be one of {', '.join(KERNELS)}; received {self.kernel!r}")

    @property
    def name(self) -> str:
        """Run name: ``level1-default``, ``level2-bmuofn``."""
        return f"level{self.level}-{self.kernel}"


@dataclass(frozen=True)
class SOMConfig:
    """The triangle maps (one per TrainSpec).

    Attributes
    ----------
    rows, cols : int
        Map size (the paper: 120 x 150).
    topology : str
        "toroidal" or "planar".
    epochs : int
        Batch epochs.
    sigma_start : float or None
        Neighbourhood radius of the first epoch in cells (None: max(rows, cols) / 4).
    sigma_end : float
        Radius of the last epoch.
    init : str
        "random" (seeded samples) or "pca".
    training : str
        "batch" or "online".
    learning_rate : float
        Start learning rate of online training.
    mirror_higher : bool
        Add mirror variations at levels >= 2 (level 1 always has them).
    seed : int
    """

    rows: int = 120
    cols: int = 150
    topology: str = "toroidal"
    epochs: int = 20
    sigma_start: float | None = None
    sigma_end: float = 1.0
    init: str = "random"
    training: str = "batch"
    learning_rate: float = 0.5
    mirror_higher: bool = False
    seed: int = 0

    def __post_init__(self):
        for name, valid in (("topology", TOPOLOGIES), ("init", INITS), ("training", TRAININGS)):
            if getattr(self, name) not in valid:
                raise ValueError(f"{name} must be one of {', '.join(valid)}; received {getattr(self, name)!r}")
        if self.rows < 2 or self.cols < 2:
            raise ValueError(f"map must be at least 2 x 2, received {self.rows} x {self.cols}")
        if self.epochs < 1:
            raise ValueError(f"epochs must be >= 1, received {self.epochs}")
        if self.sigma_start is not None and self.sigma_start <= 0:
            raise ValueError(f"sigma_start must be > 0, received {self.sigma_start}")
        if self.sigma_end <= 0:
            raise ValueError(f"sigma_end must be > 0, received {self.sigma_end}")


@dataclass(frozen=True)
class DomainConfig:
    """Domain maps (DESIGN.md §5).

    Attributes
    ----------
    sigma : float
        Gaussian smoothing of each mesh's BMU histogram on the triangle map, in cells.
    rows, cols : int
        Domain map size.
    epochs : int
    seed : int
    enabled : bool
        Build domain maps (they hold n_meshes x map units in memory: switch off for a city-sized
        corpus on a small machine).
    """

    sigma: float = 2.0
    rows: int = 8
    cols: int = 10
    epochs: int = 30
    seed: int = 0
    enabled: bool = True

    def __post_init__(self):
        if self.sigma <= 0:
            raise ValueError(f"sigma must be > 0, received {self.sigma}")
        if self.rows < 2 or self.cols < 2 or self.epochs < 1:
            raise ValueError(f"need rows, cols >= 2 and epochs >= 1, received {self.rows}, {self.cols}, {self.epochs}")


@dataclass(frozen=True)
class DaskConfig:
    """Where the work runs.

    Attributes
    ----------
    scheduler : str or None
        Address of an existing scheduler (``tcp://host:8786``); None starts a LocalCluster.
    workers : int
        Local worker processes (0: one per core).
    memory_limit : str
        Memory limit per local worker (Dask syntax, e.g. "4GB").
    shard_meshes : int
        Meshes per ingest/encode task.
    dashboard : bool
        Serve the Dask dashboard of a LocalCluster (on a free loopback port).
    """

    scheduler: str | None = None
    workers: int = 0
    memory_limit: str = "4GB"
    shard_meshes: int = 64
    dashboard: bool = True

    def __post_init__(self):
        if self.workers < 0:
            raise ValueError(f"workers must be >= 0 (0: one per core), received {self.workers}")
        if self.shard_meshes < 1:
            raise ValueError(f"shard_meshes must be >= 1, received {self.shard_meshes}")
        if self.scheduler is not None and "://" not in self.scheduler:
            raise ValueError(f"scheduler must be an address like tcp://host:8786, received {self.scheduler!r}")


@dataclass(frozen=True)
class OpenCLConfig:
    """The BMU backend.

    Attributes
    ----------
    backend : str
        "auto" (OpenCL when a device exists, else NumPy with one warning), "numpy" or "opencl".
    device : str or None
        Device selector ("0:0", a platform or device name such as "pocl" or "nvidia");
        None: ``PYOPENCL_CTX`` or the first device.
    layout : str or None
        The OpenCL kernel layouts to try, comma-separated, in order ("tiled" alone, or a chain such as
        "cpu,cpu-narrow,tiled"; layouts: "cpu", "cpu-narrow", "gpu", "tiled"; ``meshsom doctor``
        lists each device's verdicts); None: the device's fallback chain, fastest first.
    """

    backend: str = "auto"
    device: str | None = None
    layout: str | None = None

    def __post_init__(self):
        if self.backend not in BACKENDS:
            raise ValueError(f"backend must be one of {', '.join(BACKENDS)}; received {self.backend!r}")
        if self.layout is not None:
            parse_layouts(self.layout)


@dataclass(frozen=True)
class TrackingConfig:
    """MLflow tracking.

    Attributes
    ----------
    uri : str or None
        Tracking URI (``http://127.0.0.1:5000``, ``sqlite:///mlflow.db``); None: MLflow's default
        (``MLFLOW_TRACKING_URI`` or a local SQLite store).
    experiment : str
    enabled : bool
    """

    uri: str | None = None
    experiment: str = "meshsom"
    enabled: bool = True


@dataclass(frozen=True)
class ExperimentConfig:
    """A whole experiment.

    Attributes
    ----------
    name : str
    seed : int
        Master seed (sections with their own seed use theirs).
    corpus : CorpusConfig
    preprocess : PreprocessParams
    encoding : EncodingConfig
    train : tuple of TrainSpec or None
        The triangle maps to train, in order. Not given: the paper's choice for the encoded levels
        (level 1 with the default kernel and with BMUofN, every higher level with BMUofN).
    som, domain, dask, opencl, tracking : sections
    store : StoreConfig
    """

    name: str = "meshsom"
    seed: int = 0
    corpus: CorpusConfig = field(default_factory=lambda: CorpusConfig(paths=("data",)))
    preprocess: Any = None
    encoding: EncodingConfig = EncodingConfig()
    train: tuple[TrainSpec, ...] | None = None
    som: SOMConfig = SOMConfig()
    domain: DomainConfig = DomainConfig()
    dask: DaskConfig = DaskConfig()
    opencl: OpenCLConfig = OpenCLConfig()
    tracking: TrackingConfig = TrackingConfig()
    store: StoreConfig = StoreConfig()

    def __post_init__(self):
        if self.preprocess is None:
            object.__setattr__(self, "preprocess", _preprocess_params_type()())
        if self.train is None:
            specs = [TrainSpec(1, "default")] if 1 in self.encoding.levels else []
            object.__setattr__(self, "train", tuple(specs + [TrainSpec(level) for level in sorted(self.encoding.levels)]))
        missing = sorted({t.level for t in self.train} - set(self.encoding.levels))
        if missing:
            raise ValueError(
                f"train asks for level(s) {missing} that encoding.levels {list(self.encoding.levels)} does not encode"
            )


#: Field types that cannot be read from annotations (lazy imports).
_LAZY_TYPES = {(ExperimentConfig, "preprocess"): _preprocess_params_type}


def _convert(value: Any, hint: Any, key: str, source: str) -> Any:
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    if hint is Any:
        return value
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        errors = []
        for a in args:
            if a is type(None):
                continue
            try:
                return _convert(value, a, key, source)
            except ConfigError as err:
                errors.append(str(err))
        raise ConfigError(errors[0] if errors else f"{source}: {key}: invalid value {value!r}")
    if dataclasses.is_dataclass(hint):
        return build(hint, value, key, source)
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{source}: {key}: expected a list, received {type(value).__name__} {value!r}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(v, args[0], f"{key}[{i}]", source) for i, v in enumerate(value))
        if len(value) != len(args):
            raise ConfigError(f"{source}: {key}: expected a list of {len(args)} values, received {list(value)!r}")
        return tuple(_convert(v, a, f"{key}[{i}]", source) for i, (v, a) in enumerate(zip(value, args)))
    if hint is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{source}: {key}: expected true or false, received {value!r}")
        return value
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{source}: {key}: expected an integer, received {value!r}")
        return value
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{source}: {key}: expected a number, received {value!r}")
        return float(value)
    if hint is str:
        if not isinstance(value, (str, int, float)) or isinstance(value, bool):
            raise ConfigError(f"{source}: {key}: expected a string, received {value!r}")
        return str(value)
    return value


def build(cls: type, data: Any, key: str = "", source: str = "config") -> Any:
    """Build dataclass ``cls`` from a mapping, strictly.

    Parameters
    ----------
    cls : dataclass type
    data : mapping or None
        None gives the defaults.
    key : str
        Key path of ``data`` in the file, for error messages.
    source : str
        File name, for error messages.
    """
    if data is None:
        data = {}
    if isinstance(data, cls):
        return data
    if not isinstance(data, dict):
        raise ConfigError(f"{source}: {key or '(top level)'}: expected a mapping, received {type(data).__name__} {data!r}")
    hints = typing.get_type_hints(cls)
    names = [f.name for f in dataclasses.fields(cls)]
    unknown = [k for k in data if k not in names]
    if unknown:
        where = f"{key}." if key else ""
        raise ConfigError(
            f"{source}: unknown key {where}{unknown[0]!r}; valid keys{' of ' + key if key else ''}: {', '.join(names)}"
        )
    kwargs = {}
    for name in names:
        if name not in data:
            continue
        sub = f"{key}.{name}" if key else name
        hint = _LAZY_TYPES[(cls, name)]() if (cls, name) in _LAZY_TYPES else hints[name]
        kwargs[name] = _convert(data[name], hint, sub, source)
    try:
        return cls(**kwargs)
    except ConfigError:
        raise
    except (TypeError, ValueError) as err:
        raise ConfigError(f"{source}: {key or '(top level)'}: {err}") from None


def load_config(path: str | Path, overrides: dict | None = None) -> ExperimentConfig:
    """Load and validate an experiment YAML file.

    Parameters
    ----------
    path : path
    overrides : dict, optional
        Nested mapping merged over the file's content (command-line options).
    """
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as err:
        raise ConfigError(f"{path}: cannot be read ({err.strerror or err})") from None
    try:
        data = yaml.safe_load(text) or {}
    except yaml.YAMLError as err:
        raise ConfigError(f"{path}: invalid YAML: {err}") from None
    if overrides:
        data = _merge(data, overrides)
    return build(ExperimentConfig, data, "", str(path))


def _merge(base: dict, over: dict) -> dict:
    out = dict(base)
    for k, v in over.items():
        out[k] = _merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def to_dict(obj: Any) -> Any:
    """Plain nested dict/list form of a config (for YAML dumps and MLflow params)."""
    if dataclasses.is_dataclass(obj):
        return {f.name: to_dict(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, (list, tuple)):
        return [to_dict(v) for v in obj]
    return obj


def flatten(d: dict, prefix: str = "") -> dict[str, Any]:
    """``{"som": {"rows": 120}}`` -> ``{"som.rows": 120}``."""
    out = {}
    for k, v in d.items():
        name = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(flatten(v, name + "."))
        else:
            out[name] = v
    return out
