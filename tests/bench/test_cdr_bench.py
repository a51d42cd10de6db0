"""The CDR part of ``teleop-force bench``: one figure per message type and direction."""

from teleop_force.bench.cdr import cdr_figures
from teleop_force.bench.main import PARTS, add_bench_arguments, options_from_args


def test_cdr_figures_cover_every_type_in_both_directions():
    figures = cdr_figures(50)
    tables = [k for k in figures if k.endswith("_by_type")]
    assert len(tables) == 6
    types = set(figures["cdr_encode_p50_us_by_type"])
    assert len(types) == 5
    for key in tables:
        assert set(figures[key]) == types, key
        assert all(isinstance(v, float) and v > 0.0 for v in figures[key].values()), key
    assert figures["cdr_samples"] == 50


def test_only_cdr_selects_it():
    import argparse

    parser = argparse.ArgumentParser()
    add_bench_arguments(parser)
    assert "cdr" in PARTS
    only = options_from_args(parser.parse_args(["--only", "cdr"]))
    assert only.cdr and not (only.estimation or only.replay or only.messaging or only.batch)
    assert not options_from_args(parser.parse_args(["--only", "estimation"])).cdr
