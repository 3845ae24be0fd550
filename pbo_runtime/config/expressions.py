"""Job pre/post conditions: a small, safe expression language over state variables.

A condition such as `max(abs(q_m - q_d)) < 1e-3` is parsed with `ast.parse(mode="eval")` and
every node is checked against a whitelist: numbers, names (state variables), `+ - * / **`,
unary `-`, comparisons, `and`/`or`/`not`, subscripts with integer indices (`q_m[0]`,
`DH[1, 2]`) and calls of `abs, max, min, sum, all, any, norm, sqrt` without keywords.
Anything else (attributes, lambdas, comprehensions, strings, keyword arguments, dunder names)
is refused with the construct's name and its column. Evaluation walks the same tree with
numpy; nothing is ever handed to `eval`, `exec` or `compile`.

Arithmetic and comparisons are elementwise. Where a truth value is needed (the result,
`and`, `or`, `not`) an array is true when all its elements are: `q_m < 1` holds when every
joint is below 1.
"""

from __future__ import annotations

import ast
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from pbo_runtime.config.limits import MAX_CONDITION_INT

FUNCTIONS: dict[str, tuple[Callable[..., Any], int, int | None]] = {
    # name: (implementation, least arguments, most arguments or None for any number)
    "abs": (np.abs, 1, 1),
    "max": (lambda *xs: np.max(xs[0]) if len(xs) == 1 else _fold(np.maximum, xs), 1, None),
    "min": (lambda *xs: np.min(xs[0]) if len(xs) == 1 else _fold(np.minimum, xs), 1, None),
    "sum": (np.sum, 1, 1),
    "all": (np.all, 1, 1),
    "any": (np.any, 1, 1),
    "norm": (lambda x: np.linalg.norm(np.ravel(x)), 1, 1),
    "sqrt": (np.sqrt, 1, 1),
}

_BINARY: dict[type[ast.operator], Callable[[Any, Any], Any]] = {
    ast.Add: np.add,
    ast.Sub: np.subtract,
    ast.Mult: np.multiply,
    ast.Div: np.true_divide,
    ast.Pow: np.power,
}

_COMPARE: dict[type[ast.cmpop], Callable[[Any, Any], Any]] = {
    ast.Lt: np.less,
    ast.LtE: np.less_equal,
    ast.Gt: np.greater,
    ast.GtE: np.greater_equal,
    ast.Eq: np.equal,
    ast.NotEq: np.not_equal,
}

_OPERATOR_TEXT: dict[type[ast.AST], str] = {
    ast.FloorDiv: "//",
    ast.Mod: "%",
    ast.MatMult: "@",
    ast.LShift: "<<",
    ast.RShift: ">>",
    ast.BitOr: "|",
    ast.BitAnd: "&",
    ast.BitXor: "^",
    ast.Invert: "~",
    ast.UAdd: "unary +",
    ast.Is: "is",
    ast.IsNot: "is not",
    ast.In: "in",
    ast.NotIn: "not in",
}

_CONSTRUCTS: dict[type[ast.AST], str] = {
    ast.Attribute: "attribute access",
    ast.Lambda: "a lambda",
    ast.ListComp: "a comprehension",
    ast.SetComp: "a comprehension",
    ast.DictComp: "a comprehension",
    ast.GeneratorExp: "a comprehension",
    ast.IfExp: "a conditional expression (x if c else y)",
    ast.List: "a list literal",
    ast.Tuple: "a tuple",
    ast.Set: "a set literal",
    ast.Dict: "a dict literal",
    ast.Starred: "unpacking (*)",
    ast.NamedExpr: "an assignment (:=)",
    ast.JoinedStr: "an f-string",
    ast.Slice: "a slice",
    ast.Await: "await",
    ast.Yield: "yield",
    ast.YieldFrom: "yield",
}

ALLOWED = (
    "numbers, state variables, + - * / **, unary -, comparisons, and/or/not, v[i] with integer i, "
    "and calls of " + ", ".join(FUNCTIONS)
)


class ExpressionError(ValueError):
    """A condition that does not parse, or uses something the language leaves out.

    `offset` is the 0-based character offset in the condition's text; `syntax` tells a parse
    error from a refused construct, `too_large` an integer beyond the language's bound.
    """

    def __init__(self, message: str, offset: int, syntax: bool = False, too_large: bool = False) -> None:
        self.message = message
        self.offset = offset
        self.syntax = syntax
        self.too_large = too_large  # an integer beyond MAX_CONDITION_INT, written or computed
        super().__init__(f"{message} (column {offset + 1})")


@dataclass(frozen=True)
class Condition:
    """A checked condition: the names it reads, and a numpy evaluator over the parsed tree."""

    text: str
    variables: frozenset[str]
    tree: ast.Expression

    def evaluate(self, values: Mapping[str, np.ndarray]) -> bool:
        """True when the condition holds for these variable values (arrays or numbers).

        Raises KeyError for a variable missing from `values`, and ExpressionError for an
        index out of range.
        """
        result = _Evaluator(values, self.text).value(self.tree.body)
        return _truth(result)


def compile_condition(text: str) -> Condition:
    """Parse and check `text`; ExpressionError names the first refused construct and its column."""
    if not isinstance(text, str):
        raise ExpressionError(f"a condition is text, got: {type(text).__name__}", 0, syntax=True)
    try:
        tree = ast.parse(text, mode="eval")
    except SyntaxError as exc:
        offset = _offset(text, exc.lineno or 1, (exc.offset or 1) - 1, chars=True)
        raise ExpressionError(exc.msg, offset, syntax=True) from None
    names: set[str] = set()
    _Validator(text, names).check(tree.body)
    return Condition(text, frozenset(names), tree)


def _fold(op: Callable[[Any, Any], Any], xs: tuple[Any, ...]) -> Any:
    result = xs[0]
    for x in xs[1:]:
        result = op(result, x)
    return result


_WRAPPING = (ast.Add, ast.Sub, ast.Mult, ast.Pow)  # what wraps around in fixed-width integers


def _exact_beyond(op: Callable[[Any, Any], Any], left: Any, right: Any) -> bool:
    """Whether an integer result whose float64 estimate is within [2**63, 2**64) really exceeds the
    bound: worked out again with Python's exact integers (cheap, as the result is below 2**64)."""
    exact = op(np.asarray(left, dtype=object), np.asarray(right, dtype=object))
    return bool(np.any(np.abs(exact) > MAX_CONDITION_INT))


def _integers(value: Any) -> bool:
    """An integer operand: a Python int (not a flag) or an integer numpy array."""
    if isinstance(value, bool):
        return False
    return isinstance(value, int) or (isinstance(value, (np.ndarray, np.generic)) and value.dtype.kind in "iu")


def _truth(value: Any) -> bool:
    return bool(np.all(value))


def _offset(text: str, lineno: int, col: int, chars: bool = False) -> int:
    """The character offset of (lineno, col) in `text`; ast columns count UTF-8 bytes."""
    lines = text.splitlines(keepends=True) or [""]
    lineno = min(max(lineno, 1), len(lines))
    line = lines[lineno - 1]
    if not chars:
        col = len(line.encode("utf-8")[:max(col, 0)].decode("utf-8", "ignore"))
    return sum(len(x) for x in lines[: lineno - 1]) + max(col, 0)


class _Validator:
    """Walks a parsed condition and refuses every node the language leaves out."""

    def __init__(self, text: str, names: set[str]) -> None:
        self.text = text
        self.names = names

    def refuse(self, node: ast.AST, what: str) -> ExpressionError:
        offset = _offset(self.text, getattr(node, "lineno", 1), getattr(node, "col_offset", 0))
        return ExpressionError(f"{what} is not allowed in a condition", offset)

    def check(self, node: ast.expr) -> None:
        if isinstance(node, ast.Constant):
            value = node.value
            if isinstance(value, str):
                raise self.refuse(node, f"a string ({value!r})")
            if isinstance(value, bytes):
                raise self.refuse(node, "a bytes literal")
            if isinstance(value, complex):
                raise self.refuse(node, f"a complex number ({value!r})")
            if not isinstance(value, (bool, int, float)):
                raise self.refuse(node, f"the constant {value!r}")
            if isinstance(value, int) and abs(value) > MAX_CONDITION_INT:
                raise self.too_large(node, f"the integer {value}")
        elif isinstance(node, ast.Name):
            if node.id.startswith("__"):
                raise self.refuse(node, f"the dunder name '{node.id}'")
            if node.id in FUNCTIONS:
                raise self.refuse(node, f"the function '{node.id}' without a call")
            self.names.add(node.id)
        elif isinstance(node, ast.BinOp):
            if type(node.op) not in _BINARY:
                raise self.refuse(node, f"the operator '{_OPERATOR_TEXT.get(type(node.op), type(node.op).__name__)}'")
            self.check(node.left)
            self.check(node.right)
            self.constant_integer(node)  # integers written in the condition: their arithmetic must stay in bounds
        elif isinstance(node, ast.UnaryOp):
            if not isinstance(node.op, (ast.USub, ast.Not)):
                raise self.refuse(node, f"the operator '{_OPERATOR_TEXT.get(type(node.op), type(node.op).__name__)}'")
            self.check(node.operand)
        elif isinstance(node, ast.BoolOp):
            for operand in node.values:
                self.check(operand)
        elif isinstance(node, ast.Compare):
            for op in node.ops:
                if type(op) not in _COMPARE:
                    raise self.refuse(node, f"the comparison '{_OPERATOR_TEXT.get(type(op), type(op).__name__)}'")
            self.check(node.left)
            for comparator in node.comparators:
                self.check(comparator)
        elif isinstance(node, ast.Subscript):
            self.check(node.value)
            self.check_index(node.slice)
        elif isinstance(node, ast.Call):
            self.check_call(node)
        elif isinstance(node, ast.Attribute):
            raise self.refuse(node, f"attribute access ('.{node.attr}')")
        else:
            raise self.refuse(node, _CONSTRUCTS.get(type(node), f"'{type(node).__name__}'"))

    def too_large(self, node: ast.AST, what: str) -> ExpressionError:
        offset = _offset(self.text, getattr(node, "lineno", 1), getattr(node, "col_offset", 0))
        return ExpressionError(f"{what} is beyond the integers a condition computes with "
                               f"(at most {MAX_CONDITION_INT:,} = 2**63 - 1)", offset, too_large=True)

    def constant_integer(self, node: ast.expr) -> int | None:
        """The value of an integer written as constants (`10**10**10`), each step bounded before it
        is computed; None if the node is not integer constants alone."""
        if isinstance(node, ast.Constant):
            return node.value if isinstance(node.value, int) and not isinstance(node.value, bool) else None
        if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub):
            inner = self.constant_integer(node.operand)
            return None if inner is None else -inner
        if not isinstance(node, ast.BinOp) or not isinstance(node.op, (ast.Add, ast.Sub, ast.Mult, ast.Pow)):
            return None
        left, right = self.constant_integer(node.left), self.constant_integer(node.right)
        if left is None or right is None:
            return None
        if isinstance(node.op, ast.Pow):
            if right < 0:
                return None  # a float, as 10**-3 is
            if abs(left) > 1 and right * (abs(left).bit_length() - 1) > 63:  # 2**bits <= |left|: a lower bound of the result
                raise self.too_large(node, f"the integer {ast.get_source_segment(self.text, node) or 'power'}")
            result: int = left**right  # right >= 0 here: an int
        elif isinstance(node.op, ast.Mult):
            result = left * right  # operands are bounded: the product has at most 126 bits
        else:
            result = left + right if isinstance(node.op, ast.Add) else left - right
        if abs(result) > MAX_CONDITION_INT:
            raise self.too_large(node, f"the integer {ast.get_source_segment(self.text, node) or result}")
        return result

    def check_index(self, node: ast.expr) -> None:
        items = node.elts if isinstance(node, ast.Tuple) else [node]
        for item in items:
            if _integer(item) is None:
                what = _CONSTRUCTS.get(type(item)) or "an index that is not an integer"
                raise self.refuse(item, what + " (indices are integers, e.g. q_m[0] or DH[1, 2])")

    def check_call(self, node: ast.Call) -> None:
        if not isinstance(node.func, ast.Name):
            self.check(node.func)  # an attribute or a lambda: refused with its own name
            raise self.refuse(node, "a call of something that is not a function name")
        name = node.func.id
        if name not in FUNCTIONS:
            if name.startswith("__"):
                raise self.refuse(node.func, f"the dunder name '{name}'")
            raise self.refuse(node.func, f"a call of '{name}' (functions: {', '.join(FUNCTIONS)})")
        if node.keywords:
            keyword = node.keywords[0]
            label = f"the keyword argument '{keyword.arg}='" if keyword.arg else "unpacking (**)"
            raise self.refuse(keyword, label)
        _, least, most = FUNCTIONS[name]
        count = len(node.args)
        if count < least or (most is not None and count > most):
            wanted = f"{least}" if most == least else f"at least {least}"
            raise self.refuse(node, f"calling '{name}' with {count} arguments (it takes {wanted})")
        for arg in node.args:
            self.check(arg)


def _integer(node: ast.expr) -> int | None:
    if isinstance(node, ast.Constant) and isinstance(node.value, int) and not isinstance(node.value, bool):
        return node.value
    if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub):
        inner = _integer(node.operand)
        return None if inner is None else -inner
    return None


class _Evaluator:
    """Computes a validated tree with numpy; only the node types the validator let through."""

    def __init__(self, values: Mapping[str, Any], text: str) -> None:
        self.values = values
        self.text = text

    def value(self, node: ast.expr) -> Any:
        if isinstance(node, ast.Constant):
            return node.value
        if isinstance(node, ast.Name):
            return np.asarray(self.values[node.id])
        if isinstance(node, ast.BinOp):
            left, right = self.value(node.left), self.value(node.right)
            with np.errstate(all="ignore"):  # 1/0 is inf and compares as such, as in a control law
                if _integers(left) and _integers(right) and type(node.op) in _WRAPPING:
                    return self.integer_arithmetic(node, left, right)
                return _BINARY[type(node.op)](left, right)
        if isinstance(node, ast.UnaryOp):
            operand = self.value(node.operand)
            return np.negative(operand) if isinstance(node.op, ast.USub) else not _truth(operand)
        if isinstance(node, ast.BoolOp):
            is_and = isinstance(node.op, ast.And)
            for item in node.values:
                if _truth(self.value(item)) != is_and:
                    return not is_and
            return is_and
        if isinstance(node, ast.Compare):
            left = self.value(node.left)
            result: Any = True
            for op, comparator in zip(node.ops, node.comparators, strict=True):
                right = self.value(comparator)
                result = np.logical_and(result, _COMPARE[type(op)](left, right))
                left = right
            return result
        if isinstance(node, ast.Subscript):
            items = node.slice.elts if isinstance(node.slice, ast.Tuple) else [node.slice]
            index = tuple(_integer(i) for i in items)
            array = np.asarray(self.value(node.value))
            try:
                return array[index]
            except IndexError as exc:
                offset = _offset(self.text, node.lineno, node.col_offset)
                raise ExpressionError(f"index {list(index)} is out of range for shape {array.shape}: {exc}", offset) from None
        if isinstance(node, ast.Call):
            assert isinstance(node.func, ast.Name)
            function = FUNCTIONS[node.func.id][0]
            return function(*(self.value(a) for a in node.args))
        raise AssertionError(f"the validator let {type(node).__name__} through")  # our invariant

    def integer_arithmetic(self, node: ast.BinOp, left: Any, right: Any) -> Any:
        """+ - * ** of integers (an int variable, a written integer) in int64, refused where it would
        wrap around: the result is worked out in float64 first, which cannot wrap."""
        op = _BINARY[type(node.op)]
        estimate = op(np.asarray(left, dtype=np.float64), np.asarray(right, dtype=np.float64))
        if isinstance(node.op, ast.Pow) and np.any(np.asarray(right) < 0):
            return estimate  # an integer to a negative power is a fraction, as 10**-3 is
        largest = np.max(np.abs(estimate))
        if largest >= 2.0**63 and (largest >= 2.0**64 or _exact_beyond(op, left, right)):  # float64 rounds near 2**63
            offset = _offset(self.text, node.lineno, node.col_offset)
            raise ExpressionError(f"'{ast.get_source_segment(self.text, node)}' computes an integer beyond "
                                  f"{MAX_CONDITION_INT:,} (2**63 - 1), here about {largest:.3g}",
                                  offset, too_large=True)
        return op(np.asarray(left, dtype=np.int64), np.asarray(right, dtype=np.int64))
