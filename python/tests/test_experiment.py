"""Experiments: their list, a computed one and a network one with their
verdicts and data."""

import cqnet


def test_the_list_names_every_experiment():
    names = [name for name, _, _ in cqnet.experiments()]
    assert "sensor-selection" in names and "bit-allocation" in names


def test_a_network_experiment_gives_its_claims_and_data(tmp_out):
    e = cqnet.experiment("bound-aux-fim", runs=2, steps=12, threads=2, out=tmp_out, progress=False)
    assert e.name == "bound-aux-fim"
    assert e.verdict in ("holds", "does not hold", "not resolved")
    assert e.claims and all(c["runs"] == 2 for c in e.claims if c["mean_difference"] is not None)
    data = e.arrays()
    assert len(data["step"]) == 12
    assert any("auxiliary FIM" in column for column in data)
    assert e.svg.read_text().rstrip().endswith("</svg>")


def test_a_computed_experiment_holds_exactly(tmp_out):
    e = cqnet.experiment("bit-allocation", runs=1, out=tmp_out, progress=False)
    assert e.verdict == "holds"
    assert all(c["mean_difference"] is None for c in e.claims)
    assert "(12, 8)" in e.statement
