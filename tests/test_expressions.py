"""Job conditions: the restricted expression language and its numpy evaluator."""

from __future__ import annotations

import numpy as np
import pytest

from pbo_runtime.config.expressions import ExpressionError, compile_condition

Q = {"q_m": np.array([0.1, -0.2, 0.3]), "q_d": np.array([0.1, -0.2, 0.3005]), "DH": np.arange(12.0).reshape(3, 4)}


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("max(abs(q_m - q_d)) < 1e-3", True),
        ("max(abs(q_m - q_d)) < 1e-4", False),
        ("norm(q_m - q_d) <= 6e-4", True),
        ("sqrt(sum((q_m - q_d) ** 2)) < 1e-3", True),
        ("q_m[0] == 0.1 and q_m[-1] > 0", True),
        ("DH[2, 3] == 11", True),
        ("not any(abs(q_m) > 1)", True),
        ("all(q_m > -1) or q_m[0] > 5", True),
        ("q_m > 0", False),  # elementwise, true only when every element is
        ("-1 < q_m < 1", True),  # chained comparisons, elementwise
        ("min(q_m) == -0.2 and max(q_m) == 0.3", True),
        ("max(q_m, q_d)[2] == 0.3005", True),  # two arguments: elementwise maximum
        ("min(q_m, 0)[0] == 0", True),
        ("sum(q_m * 2 / 2) == sum(q_m) + 0", True),
        ("1 / 0 > 1e308", True),
        ("True", True),
    ],
)
def test_conditions_evaluate_elementwise_with_numpy(text: str, expected: bool) -> None:
    assert compile_condition(text).evaluate(Q) is expected


def test_a_condition_lists_the_variables_it_reads() -> None:
    assert compile_condition("max(abs(q_m - q_d)) < tol").variables == {"q_m", "q_d", "tol"}
    assert compile_condition("abs(1) < 2").variables == set()


def test_a_scalar_variable_works_like_a_number() -> None:
    assert compile_condition("t > 0.5 and t < 2").evaluate({"t": np.float64(1.0)})


def test_a_missing_value_is_a_key_error() -> None:
    with pytest.raises(KeyError):
        compile_condition("q_x > 0").evaluate(Q)


def test_an_index_out_of_range_is_an_expression_error() -> None:
    with pytest.raises(ExpressionError, match=r"^index \[7\] is out of range for shape \(3,\)"):
        compile_condition("q_m[7] > 0").evaluate(Q)


@pytest.mark.parametrize(
    ("text", "message", "column"),
    [
        ("__import__('os')", r"^the dunder name '__import__' is not allowed", 1),
        ("__import__('os').system('rm -rf /')", r"^attribute access \('\.system'\) is not allowed", 1),
        ("q_m.__class__", r"^attribute access \('\.__class__'\) is not allowed", 1),
        ("__builtins__", r"^the dunder name '__builtins__' is not allowed", 1),
        ("(lambda: 1)() > 0", r"^a lambda is not allowed", 2),
        ("[x for x in q_m]", r"^a comprehension is not allowed", 1),
        ("any(x > 0 for x in q_m)", r"^a comprehension is not allowed", 4),
        ("{x: 1 for x in q_m}", r"^a comprehension is not allowed", 1),
        ("q_m == 'a'", r"^a string \('a'\) is not allowed", 8),
        ("max(q_m, key=abs)", r"^the keyword argument 'key=' is not allowed", 10),
        ("q_m[1:2] > 0", r"^a slice \(indices are integers", 5),
        ("q_m[q_d] > 0", r"^an index that is not an integer", 5),
        ("q_m[0.5] > 0", r"^an index that is not an integer", 5),
        ("q_m // 2 > 0", r"^the operator '//' is not allowed", 1),
        ("q_m % 2 > 0", r"^the operator '%' is not allowed", 1),
        ("q_m @ q_d > 0", r"^the operator '@' is not allowed", 1),
        ("~q_m", r"^the operator '~' is not allowed", 1),
        ("q_m is q_d", r"^the comparison 'is' is not allowed", 1),
        ("0 in q_m", r"^the comparison 'in' is not allowed", 1),
        ("q_m if q_d else 0", r"^a conditional expression", 1),
        ("[1, 2] == q_m", r"^a list literal is not allowed", 1),
        ("open('x')", r"^a call of 'open' \(functions: abs, max, min, sum, all, any, norm, sqrt\) is not allowed", 1),
        ("eval('1')", r"^a call of 'eval'", 1),
        ("abs(q_m, q_d)", r"^calling 'abs' with 2 arguments \(it takes 1\)", 1),
        ("max()", r"^calling 'max' with 0 arguments \(it takes at least 1\)", 1),
        ("abs < 1", r"^the function 'abs' without a call is not allowed", 1),
        ("(y := 1)", r"^an assignment \(:=\) is not allowed", 2),
        ("f'{q_m}'", r"^an f-string is not allowed", 1),
        ("1j > 0", r"^a complex number", 1),
        ("b'x'", r"^a bytes literal", 1),
        ("max(*q_m)", r"^unpacking \(\*\) is not allowed", 5),
        ("q_m[0]()", r"^a call of something that is not a function name", 1),
        ("é > 0 and q_m.x", r"^attribute access \('\.x'\)", 11),  # columns count characters, not bytes
    ],
)
def test_everything_outside_the_language_is_refused_with_its_column(text: str, message: str, column: int) -> None:
    with pytest.raises(ExpressionError, match=message) as info:
        compile_condition(text)
    assert info.value.offset + 1 == column
    assert not info.value.syntax


@pytest.mark.parametrize("text", ["q_m <", "max(abs(q_m)", "", "q_m = 1", "import os"])
def test_text_that_does_not_parse_is_a_syntax_error(text: str) -> None:
    with pytest.raises(ExpressionError) as info:
        compile_condition(text)
    assert info.value.syntax


def test_the_evaluator_never_compiles_or_evals(monkeypatch: pytest.MonkeyPatch) -> None:
    import builtins

    def refuse(*args: object, **kwargs: object) -> None:
        raise AssertionError("eval/exec/compile called")

    condition = compile_condition("max(abs(q_m - q_d)) < 1e-3 and not q_m[0] > 1")
    for name in ("eval", "exec", "compile"):
        monkeypatch.setattr(builtins, name, refuse)
    assert condition.evaluate(Q)


# --- issue 18: `10**10**10 > 1` evaluated false (int64 wrapped around); integers are bounded -----------


@pytest.mark.parametrize(("text", "column"), [
    ("10**10**10 > 1", 1),
    ("9**9**9 > 1", 1),  # refused before it is computed: 9**387420489 would take minutes
    ("q_m[0] < 2**64", 10),
    ("q_m[0] < 4611686018427387904 + 4611686018427387904", 10),
    ("q_m[0] < -(3037000500 * 3037000500)", 12),
    ("q_m[0] < 18446744073709551616", 10),
])
def test_integers_written_in_a_condition_beyond_int64_are_refused_at_check_time(text: str, column: int) -> None:
    with pytest.raises(ExpressionError, match=r" is beyond the integers a condition computes with \(at most "
                                              r"9,223,372,036,854,775,807 = 2\*\*63 - 1\)") as refused:
        compile_condition(text)
    assert refused.value.too_large and not refused.value.syntax and refused.value.offset + 1 == column


@pytest.mark.parametrize(("text", "expected"), [
    ("2**62 + (2**62 - 1) > 0", True),
    ("10**-3 < 1", True),  # a fraction, as in Python
    ("10.0**400 > 1", True),  # floats overflow to inf, which compares as such
    ("NDOF**2 == 36", True),
    ("NDOF * 2**59 > 0", True),
    ("NDOF * 0 + 9223372036854775806 + 1 > 0", True),  # float64 would round it up to 2**63
])
def test_integer_arithmetic_within_int64_and_float_arithmetic_give_the_right_answer(text: str, expected: bool) -> None:
    assert compile_condition(text).evaluate({"NDOF": np.int32(6)}) is expected


@pytest.mark.parametrize("text", ["NDOF**40 > 0", "NDOF * 9223372036854775807 > 0", "-NDOF * 2**62 * 4 < 0"])
def test_integer_arithmetic_on_variables_that_would_wrap_is_refused_when_evaluated(text: str) -> None:
    condition = compile_condition(text)  # only the values tell
    with pytest.raises(ExpressionError, match=r"computes an integer beyond 9,223,372,036,854,775,807 \(2\*\*63 - 1\)"):
        condition.evaluate({"NDOF": np.array(6, dtype=np.int32)})
