"""Typed experiment configuration, loaded once from YAML into frozen dataclasses.

Every section is a frozen dataclass; the loader maps YAML mappings onto them by
field name. Unknown keys, removed keys, wrong types and invalid values are
:class:`~meshsom.errors.ConfigError` naming the source (the file, or ``--set`` for a
command-line override) and the key path (``som.epochs``), what was received and what
was expected.

The library's :class:`ExperimentConfig` holds what the computation depends on. Where
the work runs and where it is tracked (``dask:``, ``tracking:``) are pipeline settings:
``pipelines.settings.RunConfig`` extends this class with them and loads the same YAML
files through :func:`load_config` (``cls=RunConfig``).
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
        Files or folders; ``meshsom run`` resolves relative ones against the config file's folder. A URL
        (``s3://bucket/city/``, a file's, or a glob: ``s3://bucket/tiles/*.gml``) is copied to ``mirror`` to be
        read (:mod:`meshsom.mirror`).
    generator : GeneratorParams or None
        A synthetic corpus added to (or instead of) ``paths``.
    reader : ReaderOptions
    mirror : str or None
        The local folder, the same path on every machine, where inputs named by URLs are copied (and, with a store on
        object storage, what the planner makes of large inputs: a CityJSON file's split, a gzipped file's content,
        a zip's files); removed when the run is done. Default: ``meshsom-mirror`` in the temporary folder.
    """

    paths: tuple[str, ...] = ()
    generator: GeneratorParams | None = None
    reader: ReaderOptions = ReaderOptions()
    mirror: str | None = None

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
        Relative paths: ``meshsom run`` resolves them against the config file's folder.
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
    mirror_higher: bool = False
    seed: int = 0

    def __post_init__(self):
        for name, valid in (("topology", TOPOLOGIES), ("init", INITS)):
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
class ExperimentConfig:
    """A whole experiment.

    Attributes
    ----------
    name : str
    corpus : CorpusConfig
    preprocess : PreprocessParams
    encoding : EncodingConfig
    train : tuple of TrainSpec or None
        The triangle maps to train, in order. Not given: the paper's choice for the encoded levels
        (level 1 with the default kernel and with BMUofN, every higher level with BMUofN).
    som, domain, opencl : sections
    store : StoreConfig
    """

    name: str = "meshsom"
    corpus: CorpusConfig = field(default_factory=lambda: CorpusConfig(paths=("data",)))
    preprocess: Any = None
    encoding: EncodingConfig = EncodingConfig()
    train: tuple[TrainSpec, ...] | None = None
    som: SOMConfig = SOMConfig()
    domain: DomainConfig = DomainConfig()
    opencl: OpenCLConfig = OpenCLConfig()
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


#: Field types that cannot be read from annotations (lazy imports), by (class, field); subclasses inherit them.
_LAZY_TYPES = {(ExperimentConfig, "preprocess"): _preprocess_params_type}

#: Keys that configs used to have, by (class, field), and why they are gone; a config that still
#: gives one is an error that says so (subclasses inherit these).
REMOVED_KEYS = {
    (ExperimentConfig, "seed"): "it was never read; every seeded stage has its own seed "
                                "(som.seed, domain.seed, corpus.generator.seed)",
    (SOMConfig, "training"): "meshsom run trains batch maps only (online training: meshsom.som.SOM(training='online'))",
    (SOMConfig, "learning_rate"): "it set the online learning rate, and meshsom run trains batch maps only",
}

#: Where a value came from, for error messages: a file name, or a function of the key path.
Source = str | typing.Callable[[str], str]


def _where(source: Source, key: str) -> str:
    return source(key) if callable(source) else source


def _lookup(table: dict, cls: type, name: str):
    for base in cls.__mro__:
        if (base, name) in table:
            return table[(base, name)]
    return None


def _convert(value: Any, hint: Any, key: str, source: Source) -> Any:
    origin = typing.get_origin(hint)
    args = typing.get_args(hint)
    where = _where(source, key)
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
        raise ConfigError(errors[0] if errors else f"{where}: {key}: invalid value {value!r}")
    if dataclasses.is_dataclass(hint):
        return build(hint, value, key, source)
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{where}: {key}: expected a list, received {type(value).__name__} {value!r}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_convert(v, args[0], f"{key}[{i}]", source) for i, v in enumerate(value))
        if len(value) != len(args):
            raise ConfigError(f"{where}: {key}: expected a list of {len(args)} values, received {list(value)!r}")
        return tuple(_convert(v, a, f"{key}[{i}]", source) for i, (v, a) in enumerate(zip(value, args)))
    if hint is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: {key}: expected true or false, received {value!r}")
        return value
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: {key}: expected an integer, received {value!r}")
        return value
    if hint is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where}: {key}: expected a number, received {value!r}")
        return float(value)
    if hint is str:
        if not isinstance(value, (str, int, float)) or isinstance(value, bool):
            raise ConfigError(f"{where}: {key}: expected a string, received {value!r}")
        return str(value)
    return value


def build(cls: type, data: Any, key: str = "", source: Source = "config") -> Any:
    """Build dataclass ``cls`` from a mapping, strictly.

    Parameters
    ----------
    cls : dataclass type
    data : mapping or None
        None gives the defaults.
    key : str
        Key path of ``data`` in the file, for error messages.
    source : str or callable
        File name for error messages, or a function from a key path (``som.epochs``) to the
        name of where that key was given (the file, or ``--set``).
    """
    if data is None:
        data = {}
    if isinstance(data, cls):
        return data
    if not isinstance(data, dict):
        raise ConfigError(f"{_where(source, key)}: {key or '(top level)'}: expected a mapping, "
                          f"received {type(data).__name__} {data!r}")
    hints = typing.get_type_hints(cls)
    names = [f.name for f in dataclasses.fields(cls)]
    for k in data:
        why = _lookup(REMOVED_KEYS, cls, k)
        if why is not None:
            sub = f"{key}.{k}" if key else k
            raise ConfigError(f"{_where(source, sub)}: {sub} was removed: {why}; delete it from the config")
    unknown = [k for k in data if k not in names]
    if unknown:
        where = f"{key}." if key else ""
        raise ConfigError(
            f"{_where(source, where + str(unknown[0]))}: unknown key {where}{unknown[0]!r}; "
            f"valid keys{' of ' + key if key else ''}: {', '.join(names)}"
        )
    kwargs = {}
    for name in names:
        if name not in data:
            continue
        sub = f"{key}.{name}" if key else name
        lazy = _lookup(_LAZY_TYPES, cls, name)
        hint = lazy() if lazy is not None else hints[name]
        kwargs[name] = _convert(data[name], hint, sub, source)
    try:
        return cls(**kwargs)
    except ConfigError:
        raise
    except (TypeError, ValueError) as err:
        raise ConfigError(f"{_where(source, key)}: {key or '(top level)'}: {err}") from None


#: The source name of command-line overrides in error messages.
SET_SOURCE = "--set"


def parse_sets(items: typing.Iterable[str]) -> dict:
    """``["som.epochs=4", "encoding.levels=[1,2]"]`` -> ``{"som": {"epochs": 4}, "encoding": {"levels": [1, 2]}}``.

    Each value is parsed as YAML (``4`` is an integer, ``[1,2]`` a list, ``null`` None, ``x`` a string).

    Raises
    ------
    ConfigError
        An item without ``=``, an empty key or key part, or a value that is not valid YAML;
        the message names the item and the source ``--set``.
    """
    out: dict = {}
    for item in items:
        key, sep, text = str(item).partition("=")
        key = key.strip()
        parts = key.split(".")
        if not sep or not all(parts):
            raise ConfigError(f"{SET_SOURCE}: expected KEY=VALUE with a dotted key such as som.epochs=4, "
                              f"received {item!r}")
        try:
            value = yaml.safe_load(text) if text.strip() else ""
        except yaml.YAMLError as err:
            raise ConfigError(f"{SET_SOURCE}: {key}: invalid YAML value {text!r}: "
                              f"{str(err).splitlines()[0]}") from None
        node = out
        for part in parts[:-1]:
            if not isinstance(node.get(part, {}), dict):
                raise ConfigError(f"{SET_SOURCE}: {key}: {'.'.join(parts[:parts.index(part) + 1])} "
                                  f"is set to a value and used as a section")
            node = node.setdefault(part, {})
        node[parts[-1]] = value
    return out


def _key_paths(d: dict, prefix: str = "") -> list[str]:
    out = []
    for k, v in d.items():
        name = f"{prefix}{k}"
        out.append(name)
        if isinstance(v, dict):
            out += _key_paths(v, name + ".")
    return out


def load_config(path: str | Path, overrides: dict | None = None, sets: typing.Iterable[str] = (),
                cls: type = ExperimentConfig) -> Any:
    """Load and validate an experiment YAML file.

    Parameters
    ----------
    path : path
    overrides : dict, optional
        Nested mapping merged over the file's content (command-line options); errors in it
        are reported as the file's.
    sets : iterable of str
        ``KEY=VALUE`` overrides (``--set som.epochs=4``; see :func:`parse_sets`), merged last;
        errors in the keys they give name the source ``--set``.
    cls : dataclass type
        :class:`ExperimentConfig` or a subclass (``pipelines.settings.RunConfig``).
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
    source: Source = str(path)
    set_data = parse_sets(sets)
    if set_data:
        data = _merge(data, set_data) if isinstance(data, dict) else data
        given = _key_paths(set_data)

        def source(key: str, given=given) -> str:
            hit = any(key == g or key.startswith((g + ".", g + "[")) or g.startswith(key + ".") for g in given)
            return SET_SOURCE if hit else str(path)

    return build(cls, data, "", source)


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
