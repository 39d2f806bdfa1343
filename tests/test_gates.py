"""``--fail-on`` conditions (``app.gates``) as properties: how they parse and when they hold."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from aslam.app.gates import failed_conditions, parse_condition
from aslam.app.score import build_summary, summary_key, summary_keys
from aslam.core.errors import ConfigError
from aslam.core.metrics import Evaluation

KEYS = summary_keys()
OPERATORS = ("<", "<=", ">", ">=", "==", "!=")
COMPLEMENTS = {"<": ">=", "<=": ">", "==": "!="}
numbers = st.one_of(
    st.integers(-(10**6), 10**6), st.floats(-1e6, 1e6, allow_nan=False), st.sampled_from([0.0, -0.0, 1e-300])
)


def summary_with(key: str, value: object) -> dict:
    """A summary (as ``report`` makes it) whose figure ``key`` is ``value``."""
    nothing = np.zeros(0, bool)
    empty = Evaluation(
        0, np.zeros(0, np.int64), nothing, False, nothing, nothing, np.zeros((0, 3)), np.zeros((0, 3)), ()
    )
    summary = copy.deepcopy(build_summary(empty, states=0, links=0, keyframes_per_second=None))
    *sections, leaf = key.split(".")
    node = summary
    for section in sections:
        node = node[section]
    assert leaf in node
    node[leaf] = value
    return summary


@given(
    st.sampled_from(sorted(KEYS)),
    st.sampled_from(OPERATORS),
    numbers,
    st.sampled_from(["", " ", "  "]),
    st.integers(0, 4),
)
def test_a_condition_names_its_key_in_full_and_parses_back_to_itself(key, op, number, space, tail):
    """Written with the key or any tail of it that names it alone, with spaces or none: the condition
    is that key, that operator and that number, and its text (what a failure prints) parses back to
    the same condition."""
    parts = key.split(".")
    name = ".".join(parts[-1 - min(tail, len(parts) - 1) :])
    try:
        resolved = summary_key(name, KEYS)
    except ValueError:
        return  # an ambiguous tail: the parser says so (tested in test_estimate_report)
    text = f"{space}{name}{space}{op}{space}{number!r}{space}"
    condition = parse_condition(text)
    assert (condition.key, condition.op, condition.value) == (resolved, op, float(number))
    assert resolved == key if name == key else resolved.endswith("." + name)
    assert parse_condition(condition.text) == condition
    assert condition.text.startswith(resolved)


@given(
    st.sampled_from(sorted(KEYS)),
    st.one_of(st.none(), st.booleans(), numbers, st.just(math.nan)),
    numbers,
)
def test_a_measured_figure_fails_exactly_one_of_two_opposite_gates_and_an_unmeasured_one_both(
    key, actual, number
):
    """``KEY<v`` and ``KEY>=v`` (and ``<=``/``>``, ``==``/``!=``): a measured value fails exactly one
    of the two; an unmeasured one (null, NaN) fails both, so a gate never passes on a measurement
    that was not made. ``== null`` fails exactly when it is null."""
    summary = summary_with(key, actual)
    measured = actual is not None and not (isinstance(actual, float) and math.isnan(actual))
    for op, opposite in COMPLEMENTS.items():
        pair = [parse_condition(f"{key}{o}{number!r}") for o in (op, opposite)]
        failed = failed_conditions(pair, summary)
        assert len(failed) == (1 if measured else 2), (failed, actual)
        if measured:
            value = float(actual)
            held = {"<": value < number, "<=": value <= number, "==": value == number}[op]
            assert failed[0].startswith(pair[0 if held else 1].text)
    is_null = failed_conditions([parse_condition(f"{key}==null")], summary)
    assert bool(is_null) == (actual is None)
    assert bool(failed_conditions([parse_condition(f"{key}!=null")], summary)) == (actual is not None)


@pytest.mark.parametrize("raw", ["nan", "inf", "-inf", "1e999"])
def test_a_gate_on_no_finite_number_is_refused(raw):
    with pytest.raises(ConfigError, match="not a finite number"):
        parse_condition(f"keyframes<{raw}")


@pytest.mark.parametrize("raw", ["1_0", "٥", "０.5", "0x1", "1,5"])
def test_a_gate_value_is_ascii_decimal(raw):
    """``float()`` took ``1_0`` as 10 and ``٥`` as 5: ``precision<1_0`` was a gate on 10, in silence."""
    with pytest.raises(ConfigError, match="is not a number"):
        parse_condition(f"loop_closure.precision<{raw}")


@given(st.sampled_from(sorted(KEYS)), st.floats(-1e6, 1e6, allow_nan=False))
def test_a_failed_gate_names_the_value_it_was_tested_on_exactly(key, actual):
    """Rounded to 6 digits, ``recall<0.9714286`` failed on a recall shown as 0.971429, which is not
    under 0.9714286. The value is written as the summary JSON writes it: it reads back as itself."""
    [failed] = failed_conditions([parse_condition(f"{key}!=null")], summary_with(key, actual))
    shown = failed.rsplit("(is ", 1)[1].removesuffix(")")
    assert float(shown) == actual
