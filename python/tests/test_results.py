"""Results: NumPy and DataFrame forms without a second copy, the plot,
and result folders of the binary."""

import sys

import numpy as np
import pytest

import cqnet
from conftest import small_scenario

CUT = {"kind": "loss", "links": [{"from": "*", "to": "node-1"}], "at_step": 4, "duration": 3, "probability": 1.0}


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    return cqnet.sim(small_scenario(steps=10), faults=[CUT], out=tmp_path_factory.mktemp("r"))


def test_the_numpy_form(results):
    t = results.arrays("ticks")
    assert t["step"].dtype == np.uint64 and t["error"].dtype == np.float64
    assert isinstance(t["node"], list) and t["node"][0].startswith(("node-", "central"))
    n = len(t["node"])
    # Two nodes and the centralized reference for ten steps, but node-1
    # hears nothing, not even its step, for the three steps of the cut.
    assert n == 10 * 3 - 3
    assert all(len(v) == n for v in t.values())
    # A column a node leaves empty is NaN: the auxiliary-FIM bound was off.
    assert np.isnan(t["aux_bound"]).all()
    errors = np.hypot(t["est_x"] - t["true_x"], t["est_y"] - t["true_y"])
    np.testing.assert_allclose(errors, t["error"], rtol=1e-12)
    links = results.arrays("links")
    assert links["sent_bytes"].dtype == np.uint64
    assert results.bytes(kind="consensus") == int(
        sum(b for b, k in zip(links["sent_bytes"], links["kind"]) if k == "consensus")
    )


def test_the_dataframe_is_built_on_the_same_arrays(results):
    pd = pytest.importorskip("pandas")
    df = results.ticks
    assert isinstance(df, pd.DataFrame)
    arrays = results.arrays("ticks")
    assert list(df.columns) == list(arrays)
    for column in ["error", "bound", "step"]:
        assert np.shares_memory(df[column].to_numpy(), arrays[column]), column
    assert isinstance(results.links, pd.DataFrame)


def test_without_pandas_the_tables_are_dicts(results, monkeypatch):
    monkeypatch.setitem(sys.modules, "pandas", None)
    assert isinstance(results.ticks, dict)


def test_the_summary_has_its_estimates_at_the_top(results):
    s = results.summary
    assert s["rmse"] == s["estimates"]["rmse"] > 0
    assert s["faults"][0]["step"] == 4


def test_the_plot_draws_error_and_bound_per_node_and_shades_the_fault(results):
    matplotlib = pytest.importorskip("matplotlib")
    matplotlib.use("Agg")
    ax = results.plot()
    labels = [line.get_label() for line in ax.get_lines()]
    assert "node-0 error" in labels and "centralized bound" in labels
    assert len(ax.get_lines()) == 2 * 2 + 2
    assert len(ax.patches) == 1


def test_results_of_the_binary_load(cqnet_bin, tmp_out):
    import subprocess

    path = tmp_out / "s.toml"
    path.write_text(small_scenario(steps=4).to_toml())
    subprocess.run([str(cqnet_bin), "sim", str(path), "--out", str(tmp_out / "b")], check=True, capture_output=True)
    r = cqnet.Results.load(tmp_out / "b")
    assert r.summary["command"] == "sim"
    assert len(r.arrays("ticks")["step"]) == 4 * 3


def test_a_missing_file_is_a_cqnet_error(tmp_out):
    with pytest.raises(cqnet.CqnetError, match="cannot read"):
        cqnet.Results.load(tmp_out).arrays("ticks")
