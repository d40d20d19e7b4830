"""The report scripts on a tiny tracked run (configs/quick.yaml: levels 1-2, 24 labelled blocks).

One pipeline run per module (a 2-worker LocalCluster, a SQLite MLflow store in a temporary
folder); every script runs against it and must produce its files. Table 2's numbers must equal
the MLflow metrics they were read from; Figure 10's reduction must equal an independent
recomputation on the same prototypes; report.md must state every claim.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

from pipelines.settings import load_config
from pipelines.run import run_experiment

ROOT = Path(__file__).resolve().parents[1]
EXPERIMENT = "reports-test"
QUICK_RUNS = ("level1-default", "level1-bmuofn", "level2-bmuofn")


@pytest.fixture(scope="module")
def tracked(tmp_path_factory):
    """(uri, experiment, store) of one finished quick run."""
    tmp = tmp_path_factory.mktemp("reports")
    uri = f"sqlite:///{tmp / 'mlflow.db'}"
    cfg = load_config(ROOT / "configs" / "quick.yaml", {
        "store": {"path": str(tmp / "quick.zarr")},
        "tracking": {"uri": uri, "experiment": EXPERIMENT},
        "dask": {"workers": 2, "dashboard": False},
    })
    assert run_experiment(cfg, ROOT / "configs" / "quick.yaml") == 0
    return uri, EXPERIMENT, tmp / "quick.zarr"


def _args(tracked, out) -> list[str]:
    uri, exp, _ = tracked
    return ["--tracking-uri", uri, "--experiment", exp, "--out", str(out)]


def _png_and_svg(stem: Path) -> None:
    """Both files of a figure exist and are what their names say."""
    png, svg = stem.with_suffix(".png"), stem.with_suffix(".svg")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", png
    text = svg.read_text()
    assert "<svg" in text and "</svg>" in text, svg


def _final_metrics(uri: str, run_id: str) -> dict:
    """Final value (highest step) of every error metric, straight from the metric history."""
    from mlflow.tracking import MlflowClient

    client = MlflowClient(tracking_uri=uri)
    out = {}
    for key in ("t_error", "q_error", "qc_error"):
        hist = client.get_metric_history(run_id, key)
        out[key] = max(hist, key=lambda m: (m.step, m.timestamp)).value
    return out


def test_table2_numbers_equal_the_mlflow_metrics(tracked, tmp_path):
    from reports import table2
    from reports.runs import load_experiment

    assert table2.main(_args(tracked, tmp_path)) == 0
    text = (tmp_path / "table2.md").read_text()
    exp = load_experiment(tracked[0], tracked[1])
    head = [c.strip() for c in text.splitlines()[0].strip("|").split("|")]
    seen = set()
    for line in text.splitlines()[2:]:
        if not line.startswith("|"):
            break
        cells = dict(zip(head, (c.strip() for c in line.strip("|").split("|"))))
        level = int(cells["level"].rstrip("*"))
        m = exp.find(level, cells["kernel"])
        if m is None:
            assert level == 3 and cells["map"] == "not trained"
            continue
        assert cells["map"] == "12x15" and cells["dims"] == m.params["dims"]
        final = _final_metrics(tracked[0], m.run_id)
        for key, title in table2.ERRORS.items():
            assert float(cells[title]) == float(table2.format_value(final[key])), (m.name, key)
        seen.add(m.name)
    assert seen == set(QUICK_RUNS)
    assert "level 3* (bmuofn): not trained" not in text and "level 3 (bmuofn): not trained" in text
    assert "0.06560" in text  # the paper's level-1 T-error beside ours


def test_fig8_writes_the_panel_and_one_u_matrix_per_map(tracked, tmp_path, capsys):
    from reports import fig8

    assert fig8.main(_args(tracked, tmp_path)) == 0
    for stem in ["fig8"] + [f"fig8-{run}" for run in QUICK_RUNS]:
        _png_and_svg(tmp_path / stem)
    assert "level 3 (BMUofN): not trained" in capsys.readouterr().out


def test_fig9_writes_a_domain_map_per_map(tracked, tmp_path):
    from reports import fig9

    assert fig9.main(_args(tracked, tmp_path)) == 0
    for run in QUICK_RUNS:
        _png_and_svg(tmp_path / f"fig9-{run}")


def test_fig10_reduction_equals_an_independent_recomputation(tracked, tmp_path):
    import zarr

    from meshsom.standardize import destandardize, standardize
    from meshsom.synthesis import decode, reencode
    from meshsom.variations import variation_table
    from reports import fig10
    from reports.runs import load_experiment

    res = fig10.write(load_experiment(tracked[0], tracked[1]), tmp_path)
    _png_and_svg(tmp_path / "fig10")
    assert "E-" in (tmp_path / "fig10-grid.md").read_text()
    assert res["level"] == 2 and "no level-3 map" in res["note"]  # quick.yaml stops at level 2
    # independently, read with zarr directly: every unit's original by a loop, patches one by one
    g = zarr.open_group(str(tracked[2]), mode="r")
    run = g["runs"]["level2-bmuofn"]
    W = np.asarray(run["weights"][:], np.float64)
    unit, var, dist2 = (np.asarray(run[k][:]) for k in ("bmu_unit", "bmu_variation", "bmu_dist2"))
    stats = dict(g["rings"]["stats"].attrs["level2"])
    rings = standardize(np.asarray(g["rings"]["level2"][:], np.float64), stats)
    index, sign = variation_table(2)
    units = [u for u in range(len(W)) if (unit == u).any()]
    assert np.array_equal(res["units"], units)
    err = {"none": [], "lsq": []}
    for u in units:
        rows = np.flatnonzero(unit == u)
        i = rows[np.argmin(dist2[rows])]
        z = sign[var[i]] * rings[i][index[var[i]]]
        x = destandardize(W[u], stats)
        x[2::3] = np.maximum(x[2::3], fig10.V_MIN)
        for method in err:
            d = z - standardize(reencode(decode(x, 2, method, stats)), stats)
            err[method].append(np.linalg.norm(d.reshape(-1, 3), axis=1).mean())
    raw, lev = np.array(err["none"]), np.array(err["lsq"])
    m = res["measure"]
    assert m["none"]["original"] == pytest.approx(raw, rel=1e-9, abs=1e-12)
    assert m["lsq"]["original"] == pytest.approx(lev, rel=1e-6, abs=1e-9)
    assert m["reduction_pct"] == pytest.approx(100.0 * (1.0 - lev.mean() / raw.mean()), abs=1e-4)


def test_clustering_against_the_d2_baseline(tracked, tmp_path):
    from reports import clustering

    assert clustering.main(_args(tracked, tmp_path)) == 0
    text = (tmp_path / "clustering.md").read_text()
    assert "D2 baseline" in text and "level 2 (bmuofn)" in text
    values = re.findall(r"\| (0\.\d{3}|1\.000) \|", text)
    assert values  # numbers, not dashes


def test_report_writes_every_file_and_states_every_claim(tracked, tmp_path):
    from reports.report import CLAIMS, make_report

    uri, exp, _ = tracked
    res = make_report(uri, exp, tmp_path, clustering_experiment=exp, also=("no-such-experiment",), log=lambda *_: None)
    names = {Path(f).name for f in res["files"]}
    expected = {"table1.md", "table2.md", "fig8.png", "fig10.png", "clustering.md", "report.md"}
    expected |= {f"fig8-{r}.png" for r in QUICK_RUNS} | {f"fig9-{r}.png" for r in QUICK_RUNS}
    expected |= {n.replace(".png", ".svg") for n in expected if n.endswith(".png")}
    assert expected <= names
    for f in res["files"]:
        if f.endswith(".png"):
            _png_and_svg(Path(f).with_suffix(""))
    text = (tmp_path / "report.md").read_text()
    for claim in CLAIMS.values():
        assert claim in text
    assert {c["claim"] for c in res["claims"]} == set(CLAIMS)
    assert all(c["verdict"] in ("yes", "no", "partly", "not measured") for c in res["claims"])
    assert "no-such-experiment" in text and "Not tracked" in text
    assert "![Figure 8](fig8.png)" in text


def test_report_without_the_labelled_experiment_says_so(tracked, tmp_path):
    from reports.report import make_report

    uri, exp, _ = tracked
    res = make_report(uri, exp, tmp_path, clustering_experiment="absent-labels", also=(), log=lambda *_: None)
    text = (tmp_path / "report.md").read_text()
    assert "Not measured" in text and "absent-labels" in text and uri in text
    assert [c["verdict"] for c in res["claims"] if c["claim"] == "d"] == ["not measured"]
    assert not (tmp_path / "clustering.md").exists()


def test_missing_experiment_is_a_clear_error(tracked, tmp_path, capsys):
    from pipelines.cli import main as cli
    from reports import table2

    uri = tracked[0]
    assert cli(["report", "--tracking-uri", uri, "--experiment", "nope", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "'nope'" in err and uri in err
    assert table2.main(["--tracking-uri", uri, "--experiment", "nope", "--out", str(tmp_path)]) == 2
    assert "'nope'" in capsys.readouterr().err


def test_claims_from_hand_made_rows():
    from reports.report import claim_a, claim_b, claim_c

    def row(level, kernel, t, q, qc):
        return {"level": level, "kernel": kernel, "run": f"level{level}-{kernel}",
                "ours": {"t_error": t, "q_error": q, "qc_error": qc}}

    table = [row(1, "default", 0.3, 0.5, 0.2), row(1, "bmuofn", 0.4, 0.4, 0.1), row(2, "bmuofn", 0.2, 0.9, 0.3)]
    assert [c["verdict"] for c in claim_a(table)] == ["no", "yes", "yes"]
    assert [c["verdict"] for c in claim_b(table)] == ["yes", "no"]
    assert claim_b(table[:2])[0]["verdict"] == "not measured"
    measure = {"reduction_pct": 35.0, "reduction_by_depth_pct": [-38.0, 3.0, 38.0], "reduction_circular_pct": 31.0,
               "reduction_prototype_pct": 24.0, "none": {"original": np.array([1.0, 1.0])},
               "lsq": {"original": np.array([0.65, 0.65])}}
    measured = {"level": 3, "note": None, "units": np.arange(4), "measure": measure}
    assert claim_c(measured)["verdict"] == "yes"
    assert "1.00000 -> 0.65000" in claim_c(measured)["ours"]
    measure["reduction_pct"] = 10.0
    assert claim_c(measured)["verdict"] == "partly"
    measure["reduction_pct"] = 0.0
    assert claim_c(measured)["verdict"] == "no"
    assert claim_c({"level": None, "note": "no level 3"})["verdict"] == "not measured"


# ---------------------------------------------------------------------------------------------- figure quality
def _outside(fig) -> list[str]:
    """Texts beyond the figure, computed here independently of meshsom.figures.texts_outside."""
    from matplotlib.text import Text

    fig.canvas.draw()
    renderer = fig.canvas.get_renderer()
    box = fig.bbox
    drawn = set()
    for ax in fig.axes:  # tick labels matplotlib actually draws: those of ticks inside the view
        for axis in (ax.xaxis, ax.yaxis):
            lo, hi = sorted(axis.get_view_interval())
            for t in axis.get_major_ticks() + axis.get_minor_ticks():
                if lo <= t.get_loc() <= hi:
                    drawn.update((id(t.label1), id(t.label2)))
    ticks = {id(label) for ax in fig.axes for axis in (ax.xaxis, ax.yaxis)
             for t in axis.get_major_ticks() + axis.get_minor_ticks() for label in (t.label1, t.label2)}
    bad = []
    for text in fig.findobj(Text):
        if not text.get_visible() or not text.get_text().strip() or (id(text) in ticks and id(text) not in drawn):
            continue
        e = text.get_window_extent(renderer)
        if e.x0 < -1 or e.y0 < -1 or e.x1 > box.width + 1 or e.y1 > box.height + 1:
            bad.append(text.get_text())
    return bad


def test_titles_and_labels_fit_inside_every_figure(tracked):
    from meshsom.figures import texts_outside
    from meshsom.metrics import u_matrix
    from meshsom.thumbnails import draw_domain_map, render_thumbnails
    from meshsom.umatrix import u_matrix_figure
    from reports import fig8, fig9, fig10
    from reports.runs import load_experiment

    exp = load_experiment(tracked[0], tracked[1])
    figures = {"fig8": fig8.figure(exp)[0]}
    figures.update({f"fig9-{k}": f for k, f in fig9.figures(exp)[0].items()})
    res = fig10.write(exp, Path(tracked[2]).parent / "fig10-fit")
    figures["fig10"] = fig10.figure(res, "Figure 10: level-2 re-translation before and after leveling "
                                         "(experiment reports-test, level2-bmuofn), a long title that must wrap")
    rng = np.random.default_rng(0)
    figures["umatrix"] = u_matrix_figure(u_matrix(rng.normal(size=(12 * 15, 9)), 12, 15), title="U-matrix, "
                                         "level 1 (bmuofn kernel, 6x9) with a title long enough to be cut")
    # a small domain map with a long title: the case whose titles were cut at both ends
    from conftest import box

    thumbs, half = render_thumbnails([box(), box(1.0, 1.0, 3.0)] * 2, size=32)
    figures["small domain map"] = draw_domain_map(
        np.array([0, 0, 3, 5]), thumbs, 2, 3, title="Domain map from level1-default (24 meshes) " * 2,
        labels=["cube", "tall", "cube", "tall"], ids=["city.json#UUID_a1", "city.json#UUID_b2"] * 1
        + ["city.json#UUID_c3", "city.json#UUID_d4"], span=2 * half)
    for name, fig in figures.items():
        assert _outside(fig) == [], name
        assert texts_outside(fig) == [], name
    assert len(figures) == 4 + len(QUICK_RUNS)


def test_texts_outside_finds_a_cut_title():
    from meshsom.figures import new_figure, texts_outside

    fig = new_figure((3.0, 2.0), layout=None)
    ax = fig.add_subplot()
    ax.set_title("a title far too long for a figure three inches wide, so it is cut at both ends")
    title = ax.title.get_text()
    assert title in _outside(fig) and any(repr(title) in t for t in texts_outside(fig))
    ax.set_title("fits")
    fig.set_layout_engine("constrained")
    assert texts_outside(fig) == [] and _outside(fig) == []


def test_robust_limits_ignore_outliers():
    from meshsom.figures import robust_limits

    values = np.r_[np.linspace(0.0, 1.0, 999), 1e6]
    lo, hi = robust_limits(values)
    assert (lo, hi) == pytest.approx((np.percentile(values, 1), np.percentile(values, 99)))
    assert hi < 1.0 and robust_limits([2.0, 2.0]) == (1.5, 2.5)


def test_library_figures_leave_the_backend_alone(tmp_path):
    import matplotlib

    from meshsom.thumbnails import render_thumbnail
    from meshsom.umatrix import render_map
    from conftest import box

    before = matplotlib.get_backend()
    render_thumbnail(*box(), size=16)
    png = render_map(np.random.default_rng(0).normal(size=(20, 3)), 4, 5, tmp_path / "u.png")
    assert matplotlib.get_backend() == before
    _png_and_svg(Path(png).with_suffix(""))
    for module in ("meshsom/thumbnails.py", "meshsom/umatrix.py", "meshsom/figures.py"):
        source = (ROOT / module).read_text()
        assert "matplotlib.use(" not in source and "import matplotlib.pyplot" not in source, module


def test_change_text_has_no_double_negative():
    from reports.fig10 import change_text

    assert change_text(-6.3) == "6.3 % higher" and change_text(6.3) == "6.3 % lower"
    assert change_text(0.01) == "unchanged (0.0 %)"


# ---------------------------------------------------------------------------------------------- choosing runs
def test_report_run_picks_that_run(tracked, tmp_path, capsys):
    from mlflow.tracking import MlflowClient

    from pipelines.cli import main as cli
    from reports.runs import load_experiment, load_run

    uri, exp_name, store = tracked
    real = load_experiment(uri, exp_name)
    client = MlflowClient(tracking_uri=uri)
    # a newer finished pipeline run of the same experiment, with no maps: the latest, not the one asked for
    decoy = client.create_run(client.get_experiment_by_name(exp_name).experiment_id,
                              tags={"store": str(store)}, run_name="decoy")
    client.set_terminated(decoy.info.run_id, "FINISHED")
    try:
        assert load_experiment(uri, exp_name).run_id == decoy.info.run_id
        assert cli(["report", "--tracking-uri", uri, "--run", real.run_id, "--clustering-experiment", exp_name,
                    "--out", str(tmp_path)]) == 0
        out = capsys.readouterr().out
        text = (tmp_path / "report.md").read_text()
        assert f"pipeline run `{real.run_id}`" in text and decoy.info.run_id not in text
        assert {f"fig9-{r}.png" for r in QUICK_RUNS} <= {p.name for p in tmp_path.iterdir()}
        lines = [line for line in out.splitlines() if str(tmp_path) not in line]  # paths are as long as they are
        assert all(len(line) <= 80 for line in lines), max(lines, key=len)
        assert "(a) BMUofN better than the default kernel at level 1" in out and "|---" not in out
        # the figure scripts take --run too
        from reports import fig9

        assert fig9.main(["--tracking-uri", uri, "--run", real.run_id, "--out", str(tmp_path / "f9")]) == 0
        assert len(list((tmp_path / "f9").glob("fig9-*.svg"))) == len(QUICK_RUNS)
        assert set(load_run(uri, real.run_id).maps) == set(QUICK_RUNS)
    finally:
        client.delete_run(decoy.info.run_id)
    assert load_experiment(uri, exp_name).run_id == real.run_id


def test_report_unknown_or_child_run_is_a_clear_error(tracked, tmp_path, capsys):
    from pipelines.cli import main as cli
    from reports.runs import load_experiment

    uri, exp_name, _ = tracked
    assert cli(["report", "--tracking-uri", uri, "--run", "0123456789abcdef", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "no run with id '0123456789abcdef'" in err and uri in err
    child = load_experiment(uri, exp_name).find(1, "bmuofn")
    assert cli(["report", "--tracking-uri", uri, "--run", child.run_id, "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert child.run_id in err and "map run" in err and "level1-bmuofn" in err
    assert not (tmp_path / "report.md").exists()


def test_claims_text_fits_80_columns():
    from reports.report import claims_table, claims_text

    rows = [{"claim": "c", "what": "re-translation error, leveling " * 3, "paper": "30-40 % lower (level 3)",
             "ours": "level 3, 1353 prototypes, QC-error against their originals: 0.00825 -> 0.00648 " * 4,
             "verdict": "not measured"}]
    text = claims_text(rows)
    assert max(len(line) for line in text.splitlines()) <= 80
    assert "not measured" in text and "0.00648" in text
    assert max(len(line) for line in claims_table(rows).splitlines()) > 80  # the Markdown keeps its long lines
