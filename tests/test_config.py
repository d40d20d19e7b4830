import pytest

from meshsom.config import ExperimentConfig, flatten, load_config, to_dict
from meshsom.errors import ConfigError


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
