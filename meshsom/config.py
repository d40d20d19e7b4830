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
    """Which ring levels are encoded.

    Attributes
    ----------
    levels : tuple of int
        Ring levels to encode (1..8).
    """

    levels: tuple[int, ...] = (1, 2, 3)

    def __post_init__(self):
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
    store : StoreConfig
    """

    name: str = "meshsom"
    seed: int = 0
    corpus: CorpusConfig = field(default_factory=lambda: CorpusConfig(paths=("data",)))
    preprocess: Any = None
    encoding: EncodingConfig = EncodingConfig()
    store: StoreConfig = StoreConfig()

    def __post_init__(self):
        if self.preprocess is None:
            object.__setattr__(self, "preprocess", _preprocess_params_type()())


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
