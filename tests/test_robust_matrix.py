"""The robust-revisit matrix's scenarios on route files (the held-out routes in bench/routes/)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[1] / "bench"
sys.path.insert(0, str(BENCH))

from robust_matrix import HELD_OUT_ROUTES, Scenario, main  # noqa: E402

from aslam.recorder.routes import resolve_route  # noqa: E402


@pytest.mark.parametrize("route", HELD_OUT_ROUTES)
def test_a_held_out_route_is_closed_and_driven_twice_under_its_own_name(route):
    path = str(BENCH.parent / route)
    assert resolve_route(path).is_closed
    scenario = Scenario("lighting50", path, 6)
    stem = Path(route).stem
    assert scenario.name == f"lighting50-{stem}-seed6"
    assert scenario.record_config().laps == 2
    assert scenario.command().startswith(f"aslam record --route {route} --laps 2 --seed 6 ")
    assert Scenario("kidnap", path, 6).base.name == f"default-{stem}-seed6"


def test_a_route_that_is_neither_a_preset_nor_a_file_is_refused(capsys):
    with pytest.raises(SystemExit):
        main(["--routes", "nowhere.json", "--render-only"])
    assert "neither a preset" in capsys.readouterr().err
