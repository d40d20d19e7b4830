from pathlib import Path

import pytest

from meshsom.config import ExperimentConfig, flatten, load_config, to_dict
from meshsom.errors import ConfigError


CONFIGS = Path(__file__).resolve().parents[1] / "configs"


def _write(tmp_path, text):
    p = tmp_path / "c.yaml"
    p.write_text(text)
    return p


def test_valid_config_builds_typed_sections(tmp_path):
    cfg = load_config(_write(tmp_path, """
name: t
corpus:
  paths: [data/real]
  generator: {n_blocks: 4, seed: 2, families: [L, U]}
  reader: {lod: "2.2", parts: separate}
encoding: {levels: [1, 2]}
"""))
    assert isinstance(cfg, ExperimentConfig)
    assert cfg.corpus.paths == ("data/real",)
    assert cfg.corpus.generator.families == ("L", "U") and cfg.corpus.generator.n_blocks == 4
    assert cfg.corpus.reader.lod == "2.2" and cfg.encoding.levels == (1, 2)
    flat = flatten(to_dict(cfg))
    assert flat["corpus.generator.seed"] == 2 and flat["encoding.levels"] == [1, 2]


@pytest.mark.parametrize(
    "text, message",
    [
        ("corpus: {paths: [a], colour: red}", "unknown key corpus.'colour'"),
        ("encoding: {levels: [0]}", "encoding: levels must lie in 1..8, received 0"),
        ("encoding: {levels: one}", "encoding.levels: expected a list"),
        ("store: {chunk_rows: 1.5}", "store.chunk_rows: expected an integer, received 1.5"),
        ("corpus: {paths: [a], reader: {parts: glue}}", "parts must be one of merge, separate; received 'glue'"),
        ("preprocess: {weld_tol: -1}", "preprocess"),
        ("nme: x", "unknown key 'nme'"),
        ("corpus: [1, 2", "invalid YAML"),
    ],
)
def test_bad_configs_name_file_and_key(tmp_path, text, message):
    with pytest.raises(ConfigError) as err:
        load_config(_write(tmp_path, text))
    assert message in str(err.value)
    assert "c.yaml" in str(err.value)


def test_missing_file(tmp_path):
    with pytest.raises(ConfigError, match="cannot be read"):
        load_config(tmp_path / "nope.yaml")


@pytest.mark.parametrize(
    "text, message",
    [
        ("seed: 0", "c.yaml: seed was removed: it was never read"),
        ("som: {training: online}", "c.yaml: som.training was removed: meshsom run trains batch maps only"),
        ("som: {learning_rate: 0.3}", "c.yaml: som.learning_rate was removed"),
    ],
)
def test_removed_keys_say_so(tmp_path, text, message):
    with pytest.raises(ConfigError) as err:
        load_config(_write(tmp_path, "corpus: {generator: {n_blocks: 2}}\n" + text))
    assert message in str(err.value)


def test_pipeline_sections_are_not_the_librarys(tmp_path):
    """dask: and tracking: belong to pipelines.settings.RunConfig; the library config rejects them."""
    from pipelines.settings import RunConfig
    from pipelines.settings import load_config as load_run_config

    text = "corpus: {generator: {n_blocks: 2}}\ndask: {workers: 3}\ntracking: {enabled: false}\n"
    with pytest.raises(ConfigError, match="unknown key 'dask'"):
        load_config(_write(tmp_path, text))
    cfg = load_run_config(_write(tmp_path, text))
    assert isinstance(cfg, RunConfig) and isinstance(cfg, ExperimentConfig)
    assert cfg.dask.workers == 3 and cfg.tracking.enabled is False
    assert "dask" not in {f for f in ExperimentConfig.__dataclass_fields__}
    assert flatten(to_dict(cfg))["dask.workers"] == 3


def test_set_items_parse_as_yaml_into_nested_keys():
    from meshsom.config import parse_sets

    assert parse_sets(["som.epochs=4", "encoding.levels=[1,2]", "opencl.device=null", "name=x=y"]) == {
        "som": {"epochs": 4}, "encoding": {"levels": [1, 2]}, "opencl": {"device": None}, "name": "x=y"}
    for bad in ("som.epochs", "=4", "som..epochs=4"):
        with pytest.raises(ConfigError, match=r"--set: expected KEY=VALUE"):
            parse_sets([bad])


@pytest.mark.parametrize(
    "key, value, message",
    [
        ("som.epochs", "x", "som.epochs: expected an integer, received 'x'"),
        ("som.epochs", "0", "som: epochs must be >= 1, received 0"),
        ("som.rwos", "3", "unknown key som.'rwos'; valid keys of som:"),
        ("encoding.levels", "one", "encoding.levels: expected a list"),
        ("som.training", "online", "som.training was removed: meshsom run trains batch maps only"),
    ],
)
def test_bad_set_gets_the_yaml_error_with_source_set(tmp_path, key, value, message):
    """The same key and value in the file and as --set: the same error text, only the source differs."""
    base = "corpus: {generator: {n_blocks: 2}}\n"
    section, name = key.split(".")
    with pytest.raises(ConfigError) as from_file:
        load_config(_write(tmp_path, base + f"{section}: {{{name}: {value}}}\n"))
    with pytest.raises(ConfigError) as from_set:
        load_config(_write(tmp_path, base), sets=[f"{key}={value}"])
    assert message in str(from_file.value)
    assert str(from_set.value) == str(from_file.value).replace(str(tmp_path / "c.yaml"), "--set", 1)
    assert str(from_set.value).startswith("--set: ")


def test_set_overrides_the_file_and_options(tmp_path):
    p = _write(tmp_path, "corpus: {generator: {n_blocks: 2}}\nsom: {epochs: 9, rows: 5}\n")
    cfg = load_config(p, {"som": {"epochs": 7}}, sets=["som.epochs=3", "encoding.levels=[1]"])
    assert cfg.som.epochs == 3 and cfg.som.rows == 5 and cfg.encoding.levels == (1,)
    assert [t.name for t in cfg.train] == ["level1-default", "level1-bmuofn"]


def test_resolve_paths_against_the_config_folder(tmp_path):
    from pipelines.settings import load_config as load_run_config
    from pipelines.settings import resolve_paths

    folder = tmp_path / "cfgs"
    folder.mkdir()
    p = folder / "c.yaml"
    p.write_text(f"corpus: {{paths: [../data/a.obj, {tmp_path / 'abs.obj'}]}}\nstore: {{path: out/s.zarr}}\n"
                 "tracking: {uri: 'sqlite:///db/m.db'}\n")
    cfg = resolve_paths(load_run_config(p), p.parent)
    assert cfg.corpus.paths == (str(tmp_path / "data" / "a.obj"), str(tmp_path / "abs.obj"))
    assert cfg.store.path == str(folder / "out" / "s.zarr")
    assert cfg.tracking.uri == f"sqlite:///{folder / 'db' / 'm.db'}"
    s3 = resolve_paths(load_run_config(p, sets=["store.path=s3://bucket/x.zarr"]), p.parent)
    assert s3.store.path == "s3://bucket/x.zarr"


@pytest.mark.parametrize("name", sorted(p.name for p in CONFIGS.glob("*.yaml")))
def test_every_shipped_config_loads_and_finds_its_inputs(name):
    from pipelines.settings import load_config as load_run_config, resolve_paths

    path = CONFIGS / name
    cfg = resolve_paths(load_run_config(path), path.parent)
    assert all(Path(p).exists() for p in cfg.corpus.paths), cfg.corpus.paths
    if name == "zurich-lod2.yaml":
        assert cfg.preprocess.roof_envelope and cfg.preprocess.wall_tilt_deg == 5.0
