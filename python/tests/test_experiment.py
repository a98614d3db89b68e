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


def test_a_computed_experiment_gives_its_exact_and_its_paired_claims(tmp_out):
    e = cqnet.experiment("bit-allocation", runs=1, out=tmp_out, progress=False)
    assert e.verdict == "holds"
    exact = [c for c in e.claims if c["mean_difference"] is None]
    paired = [c for c in e.claims if c["mean_difference"] is not None]
    # The optima are computed; the estimators' MSEs are Monte Carlo over
    # draws the allocations share, judged draw by draw.
    assert any("(12, 8)" in c["claim"] for c in exact)
    assert paired and all(c["runs"] == 40000 for c in paired)
    assert "(12, 8)" in e.statement
