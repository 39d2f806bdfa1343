"""A few seconds of the fuzz in ``tests/fuzz.py`` on every test run (the long run: ``make fuzz``).

Hypothesis draws the kind of hostile input (a damaged recording, estimate file or route file, or
hostile option values) and the random seed of its damage; each case must keep the error contract:
exit 0 or 2, nothing on stderr on success and exactly one ``aslam: error:`` line on failure, no
traceback, inputs byte-identical, and after a failure nothing under any output name.
"""

from __future__ import annotations

import random
import shutil

import fuzz  # tests/fuzz.py: the harness `make fuzz` runs long
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st


@pytest.fixture(scope="module")
def seeds(tmp_path_factory: pytest.TempPathFactory):
    return fuzz.make_seeds(tmp_path_factory.mktemp("fuzz-seeds"))


@settings(
    max_examples=40,
    deadline=None,
    derandomize=True,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
@given(kind=st.sampled_from(fuzz.KINDS), seed=st.integers(0, 2**32 - 1))
def test_hostile_inputs_keep_the_error_contract(seeds, tmp_path_factory, kind: str, seed: int):
    folder = tmp_path_factory.mktemp(f"fuzz-{kind}")
    try:
        case = fuzz.MAKERS[kind](seeds, folder, random.Random(seed))
        outcome = fuzz.run_case(case)
        assert outcome.problems == [], (outcome.argv, outcome.code, outcome.stderr)
    finally:
        shutil.rmtree(folder, ignore_errors=True)


def test_the_seeds_are_valid_inputs(seeds):
    """The fuzz starts from inputs that work, so its exit-2s come from the damage."""
    from aslam.cli.app import main

    assert main(["info", str(seeds.plain), "-q", "--json", "-"]) == 0
    assert main(["report", str(seeds.estimate), "-q", "--recording", str(seeds.plain)]) == 0
