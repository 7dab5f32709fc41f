"""BehaviorTree.CPP v4's script language (the subset Objectives use), parsed once, run many times.

``compile_script`` turns source text into a ``Script`` at load time, so a syntax error stops the
load with the column where it is; ``Script.evaluate(blackboard)`` runs it and returns the value of
the last statement. Nothing here uses Python's eval/exec: the source is tokenized, parsed into a
small tree of nodes, and each node computes its value.

The language, as BT.CPP 4.8 runs it (checked against its parser and against behaviortreepy):

- values: integers (``42``, ``0x1F``), reals (``2.5``, ``1e-3``), strings in single or double
  quotes (no escapes), ``true`` / ``false``, and blackboard entries by name (``@name`` is the root
  blackboard's entry);
- statements separated by ``;`` (a trailing ``;`` is allowed);
- ``name := value`` creates the entry (or assigns it when it exists); ``name = value`` assigns an
  entry that must exist; ``+= -= *= /=`` update an existing entry. Assigning keeps the type the
  entry already has: an integer entry takes ``2.0`` as ``2`` and refuses ``2.5``, a number entry
  takes the string ``'7'`` as ``7``, a string entry refuses numbers;
- operators, loosest first: assignment, ``c ? a : b`` (not chainable), ``&&`` and ``||`` (one
  level, left to right, both sides always evaluated), comparisons ``== != < <= > >=`` (chainable:
  ``a < b < c`` means both hold), ``..`` (string concatenation), ``| ^``, ``&``, ``+ -``,
  ``* /``, and the prefixes ``-``, ``!``, ``~``. Arithmetic and bitwise operators (``!`` counts
  as bitwise, as in BT.CPP) cannot be mixed without parentheses: ``!a + 1`` is an error;
- arithmetic works on doubles and gives a double (``1 + 2`` is ``3.0``; integer literals stay
  integers until an operator touches them); ``'a' + 'b'`` also concatenates;
- a comparison between a string and a number reads the string as a number (``'true'`` and
  ``'false'`` read as 1 and 0), so an entry holding ``'42'`` equals ``42``; ``==`` on numbers
  allows the float epsilon (1.19e-7), as BT.CPP does.

Where this module differs from BT.CPP 4.8.2, on purpose:

- ``+ - * /`` group left to right (``10 - 2 - 3`` is 5). BT.CPP up to 4.8 grouped them right to
  left (its bug #1029, fixed upstream in PR #1069).
- comparisons, ``&& || !`` give Python booleans (BT.CPP gives 1.0 / 0.0); ``true`` is ``True``
  (BT.CPP stores the integer 1). Both behave the same in arithmetic and conditions.
- ``..`` accepts two numbers too (BT.CPP refuses them); it writes a double as BT.CPP does
  (``'x=' .. 2.5`` is ``x=2.500000``) but a comparison's result as ``true`` / ``false``;
  ``x / 0`` is an error, not ``inf``; a string longer than ``MAX_STRING_CHARS`` is an error.
- ``a .. b + c`` means ``a .. (b + c)``; BT.CPP 4.8 refuses to mix them without parentheses.

Names ``and``, ``or`` and ``not`` are not operators in BT.CPP; using them gets an error that says
which operator to write instead.
"""
from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field
from typing import Any, Protocol

from runtime.errors import ObjectiveError
from .ports import to_xml_string

MAX_SOURCE_CHARS = 10_000
"""Longest script accepted."""

MAX_DEPTH = 200
"""Deepest nesting accepted: parentheses, ternary branches and stacked prefix operators."""

MAX_STRING_CHARS = 1_000_000
"""Longest string a script may build (``..``, ``+``, ``+=``): a script that doubles a string in
a loop stops here with an error instead of filling the memory."""

FLOAT_EPSILON = 1.1920928955078125e-07
"""``==`` on numbers tolerates this absolute difference (BT.CPP uses float's epsilon)."""


class BlackboardLike(Protocol):
    def has(self, key: str) -> bool: ...

    def get(self, key: str) -> Any: ...

    def set(self, key: str, value: Any) -> None: ...


class ScriptError(ObjectiveError):
    """A script that does not parse, or a statement that cannot be evaluated.

    ``message`` says what is wrong, ``column`` (1-based, counted from the start of the source)
    where; ``str()`` gives ``"<message> at column <n>"``.
    """

    def __init__(self, message: str, column: int | None = None) -> None:
        self.message = message
        self.column = column
        super().__init__(f"{message} at column {column}" if column else message)


# --------------------------------------------------------------------------------------------
# Tokens
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Token:
    kind: str  # "number", "string", "name", "bool", "op", "end"
    text: str
    column: int
    value: Any = None


# Longest first, so ":=" wins over ":" and "==" over "=".
_OPERATORS = (
    ":=", "+=", "-=", "*=", "/=", "==", "!=", "<=", ">=", "&&", "||", "..",
    "=", "+", "-", "*", "/", "<", ">", "!", "~", "&", "|", "^", "?", ":", "(", ")", ";",
)  # fmt: skip
_WHITESPACE = " \t\r\n"


def _describe_token(token: Token) -> str:
    if token.kind == "end":
        return "end of script"
    if token.kind == "string":
        return f"string {token.text}"
    if token.kind in ("number", "bool"):
        return f"{token.text}"
    if token.kind == "name":
        return f"name '{token.text}'"
    return f"'{token.text}'"


MAX_SCRIPT_INT = 2**63 - 1
"""The largest integer literal a script takes (BT.CPP's scripts read integers as 64-bit)."""


def _integer(digits: str, base: int, text: str, column: int) -> int:
    """The value of an integer literal's ``digits``; ScriptError naming it past ``MAX_SCRIPT_INT``
    (checked on the length first: a 5,000-digit literal is refused without converting it)."""
    significant = digits.lstrip("0")
    if len(significant) <= 20 and int(significant or "0", base) <= MAX_SCRIPT_INT:
        return int(significant or "0", base)
    shown = text if len(text) <= 30 else f"{text[:20]}... ({len(text)} characters)"
    raise ScriptError(f"integer {shown} is too large: a script's integers are 64-bit (at most {MAX_SCRIPT_INT})", column)


def _read_number(source: str, start: int) -> Token:
    """A decimal or hex integer, or a real with a fraction and/or an exponent."""
    i, n = start, len(source)
    column = start + 1
    if source.startswith(("0x", "0X"), start):
        i += 2
        while i < n and source[i] in "0123456789abcdefABCDEF":
            i += 1
        if i == start + 2:
            raise ScriptError(f"invalid number '{source[start:i]}'", column)
        text = source[start:i]
        value: int | float = _integer(source[start + 2 : i], 16, text, column)
    else:
        while i < n and source[i].isdigit():
            i += 1
        is_real = False
        if i + 1 < n and source[i] == "." and source[i + 1].isdigit():
            is_real = True
            i += 1
            while i < n and source[i].isdigit():
                i += 1
        if i < n and source[i] in "eE":
            j = i + 1
            if j < n and source[j] in "+-":
                j += 1
            if j < n and source[j].isdigit():
                is_real = True
                i = j
                while i < n and source[i].isdigit():
                    i += 1
        text = source[start:i]
        value = float(text) if is_real else _integer(text, 10, text, column)
    # "12abc", "1.", "1.5.2" are typos, not a number followed by something else.
    if i < n and (source[i].isalnum() or source[i] == "_" or (source[i] == "." and source[i : i + 2] != "..")):
        end = i
        while end < n and (source[end].isalnum() or source[end] in "_."):
            end += 1
        raise ScriptError(f"invalid number '{source[start:end]}'", column)
    return Token("number", text, column, value)


def tokenize(source: str) -> list[Token]:
    """Split ``source`` into tokens; the last one is always ``end``."""
    tokens: list[Token] = []
    i, n = 0, len(source)
    while i < n:
        char = source[i]
        if char in _WHITESPACE:
            i += 1
            continue
        column = i + 1
        if char.isdigit():
            token = _read_number(source, i)
            tokens.append(token)
            i += len(token.text)
            continue
        if char in "'\"":
            end = source.find(char, i + 1)
            if end < 0:
                raise ScriptError(f"unterminated string (the {char} is never closed)", column)
            tokens.append(Token("string", source[i : end + 1], column, source[i + 1 : end]))
            i = end + 1
            continue
        if char.isalpha() or char in "_@":
            j = i + 1
            while j < n and (source[j].isalnum() or source[j] == "_"):
                j += 1
            word = source[i:j]
            if word == "@":
                raise ScriptError("'@' must be followed by an entry name", column)
            if word in ("true", "false"):
                tokens.append(Token("bool", word, column, word == "true"))
            else:
                tokens.append(Token("name", word, column, word))
            i = j
            continue
        for op in _OPERATORS:
            if source.startswith(op, i):
                tokens.append(Token("op", op, column))
                i += len(op)
                break
        else:
            raise ScriptError(f"unexpected character {char!r}", column)
    tokens.append(Token("end", "", n + 1))
    return tokens


# --------------------------------------------------------------------------------------------
# Values: what scripts compute with
# --------------------------------------------------------------------------------------------
def _is_bool(value: Any) -> bool:
    return isinstance(value, bool) or type(value).__name__ == "bool_"  # numpy.bool_ too


def _is_number(value: Any) -> bool:
    """bool, int and float all count as numbers, as in BT.CPP."""
    return _is_bool(value) or (isinstance(value, numbers.Real) and not isinstance(value, str))


def _is_integral(value: Any) -> bool:
    return _is_bool(value) or isinstance(value, numbers.Integral)


def _describe(value: Any) -> str:
    if value is None:
        return "nothing (None)"
    if _is_bool(value):
        return "true" if value else "false"
    if isinstance(value, str):
        return f"the string {value!r}"
    if _is_number(value):
        return to_xml_string(value if isinstance(value, (int, float)) else float(value))
    return f"a {type(value).__name__}"


def _text(value: Any) -> str:
    """How ``..`` writes a value: strings as they are, integers as digits, doubles with six
    decimals as BT.CPP's ``std::to_string`` does (``2.500000``)."""
    if isinstance(value, str):
        return value
    if _is_bool(value):
        return "true" if value else "false"
    if _is_integral(value):
        return str(int(value))
    return f"{float(value):f}"


def _joined(first: str, second: str, column: int | None) -> str:
    """``first + second``, or ScriptError when that is longer than ``MAX_STRING_CHARS``."""
    length = len(first) + len(second)
    if length > MAX_STRING_CHARS:
        raise ScriptError(f"the string would be {length} characters long; scripts build strings of at most {MAX_STRING_CHARS}", column)
    return first + second


def _string_as_number(text: str) -> float | None:
    """The number a string stands for in a comparison, or None when it is not one."""
    stripped = text.strip()
    if stripped in ("true", "false"):
        return 1.0 if stripped == "true" else 0.0
    try:
        return float(stripped)
    except ValueError:
        try:
            return float(int(stripped, 16)) if stripped.lower().startswith("0x") else None
        except ValueError:
            return None


def truth(value: Any, what: str = "the condition") -> bool:
    """BT.CPP's truthiness: a bool, a non-zero number, or the strings 'true' / 'false'.

    Any other value is an error: a string like 'yes' or an empty entry is a mistake in the
    Objective, not a quiet false.
    """
    if _is_bool(value):
        return bool(value)
    if _is_number(value):
        if isinstance(value, float) and math.isnan(value):
            raise ScriptError(f"{what} is NaN, which is neither true nor false")
        nonzero: bool = value != 0
        return nonzero
    if isinstance(value, str) and value.strip() in ("true", "True", "TRUE", "false", "False", "FALSE"):
        return value.strip().lower() == "true"
    raise ScriptError(f"{what} gave {_describe(value)}, which is neither true nor false")


# --------------------------------------------------------------------------------------------
# The syntax tree
# --------------------------------------------------------------------------------------------
class Node:
    """A piece of a parsed script; ``evaluate`` computes its value against a blackboard."""

    column: int
    family: str | None = None  # "math" or "bits" for operators that may not be mixed

    def evaluate(self, board: BlackboardLike) -> Any:
        raise NotImplementedError

    def operand(self, value: Any) -> str:
        """How an error message names this operand: the entry's name, or the value itself."""
        return _describe(value)


@dataclass
class Literal(Node):
    value: Any
    column: int

    def evaluate(self, board: BlackboardLike) -> Any:
        return self.value


@dataclass
class Name(Node):
    """A blackboard entry; reading one that does not exist (or holds None) is an error."""

    name: str
    column: int

    def evaluate(self, board: BlackboardLike) -> Any:
        if not board.has(self.name):
            raise ScriptError(f"blackboard entry '{self.name}' does not exist", self.column)
        value = board.get(self.name)
        if value is None:
            raise ScriptError(f"blackboard entry '{self.name}' is empty (None)", self.column)
        return value

    def operand(self, value: Any) -> str:
        return f"'{self.name}' ({_describe(value)})"


@dataclass
class Group(Node):
    """A parenthesized expression: operators inside it do not mix with those outside."""

    inner: Node
    column: int

    def evaluate(self, board: BlackboardLike) -> Any:
        return self.inner.evaluate(board)

    def operand(self, value: Any) -> str:
        return self.inner.operand(value)


@dataclass
class Unary(Node):
    op: str  # "-", "!", "~"
    rhs: Node
    column: int

    def __post_init__(self) -> None:
        self.family = "math" if self.op == "-" else "bits"

    def evaluate(self, board: BlackboardLike) -> Any:
        value = self.rhs.evaluate(board)
        if not _is_number(value):
            raise ScriptError(f"'{self.op}' needs a number, got {self.rhs.operand(value)}", self.column)
        if self.op == "-":
            return -float(value)
        if self.op == "!":
            return not value
        if not _is_integral(value) and not float(value).is_integer():
            raise ScriptError(f"'~' needs an integer, got {self.rhs.operand(value)}", self.column)
        return ~int(value)


def _arithmetic(op: str, lhs: Any, rhs: Any, column: int | None = None) -> Any:
    if op == "+" and isinstance(lhs, str) and isinstance(rhs, str):
        return _joined(lhs, rhs, column)
    if not (_is_number(lhs) and _is_number(rhs)):
        return NotImplemented
    a, b = float(lhs), float(rhs)
    if op == "+":
        return a + b
    if op == "-":
        return a - b
    if op == "*":
        return a * b
    if b == 0:
        raise ZeroDivisionError
    return a / b


def _bitwise(op: str, lhs: Any, rhs: Any) -> Any:
    def integer(value: Any) -> int | None:
        if _is_integral(value):
            return int(value)
        if _is_number(value) and float(value).is_integer():
            return int(value)
        return None

    a, b = integer(lhs), integer(rhs)
    if a is None or b is None:
        return NotImplemented
    return a & b if op == "&" else a | b if op == "|" else a ^ b


@dataclass
class Chain(Node):
    """Operands joined left to right by operators of one precedence level: ``a - b + c``."""

    level: int
    operands: list[Node]
    ops: list[tuple[str, int]]  # (operator, column)
    column: int = 0

    def __post_init__(self) -> None:
        self.column = self.ops[0][1]
        self.family = "math" if self.level >= SUM else "bits" if self.level >= BIT_OR else None

    def evaluate(self, board: BlackboardLike) -> Any:
        if self.level == LOGICAL:
            return self._logical(board)
        first = self.operands[0]
        value = first.evaluate(board)
        described = first.operand(value)
        for (op, column), node in zip(self.ops, self.operands[1:]):
            rhs = node.evaluate(board)
            if op == "..":
                if not (isinstance(value, str) or _is_number(value)) or not (isinstance(rhs, str) or _is_number(rhs)):
                    result: Any = NotImplemented
                else:
                    result = _joined(_text(value), _text(rhs), column)
            elif op in "&|^":
                result = _bitwise(op, value, rhs)
                if result is NotImplemented:
                    raise ScriptError(
                        f"'{op}' needs two integers, got {described} and {node.operand(rhs)}", column
                    )
            else:
                try:
                    result = _arithmetic(op, value, rhs, column)
                except ZeroDivisionError:
                    raise ScriptError(f"division by zero: {described} / {node.operand(rhs)}", column) from None
            if result is NotImplemented:
                raise ScriptError(f"cannot apply '{op}' to {described} and {node.operand(rhs)}", column)
            value = result
            described = _describe(value)
        return value

    def _logical(self, board: BlackboardLike) -> bool:
        # BT.CPP evaluates every operand (no short-circuit), so a missing entry is always reported.
        values = [node.evaluate(board) for node in self.operands]
        for index, (node, value) in enumerate(zip(self.operands, values)):
            if not _is_number(value):
                op, column = self.ops[max(0, index - 1)]
                hint = " (compare strings with '==' first)" if isinstance(value, str) else ""
                raise ScriptError(f"'{op}' needs true/false or numbers, got {node.operand(value)}{hint}", column)
        result = bool(values[0])
        for (op, _), value in zip(self.ops, values[1:]):
            result = (result and bool(value)) if op == "&&" else (result or bool(value))
        return result


def _compare(op: str, lhs: Any, rhs: Any) -> bool | None:
    """``lhs op rhs``, or None when the two cannot be compared."""
    if isinstance(lhs, str) and isinstance(rhs, str):
        a: Any = lhs
        b: Any = rhs
    elif _is_number(lhs) and _is_number(rhs):
        a, b = float(lhs), float(rhs)
    elif isinstance(lhs, str) and _is_number(rhs):
        a, b = _string_as_number(lhs), float(rhs)
    elif _is_number(lhs) and isinstance(rhs, str):
        a, b = float(lhs), _string_as_number(rhs)
    else:
        return None
    if a is None or b is None:
        return None
    if op in ("==", "!="):
        same = abs(a - b) <= FLOAT_EPSILON if isinstance(a, float) else a == b
        return same if op == "==" else not same
    # two floats or two strings: each comparison is a bool
    if op == "<":
        return bool(a < b)
    if op == "<=":
        return bool(a <= b)
    if op == ">":
        return bool(a > b)
    return bool(a >= b)


@dataclass
class Compare(Node):
    """``a < b <= c``: true when every neighbouring pair holds; stops at the first that fails."""

    operands: list[Node]
    ops: list[tuple[str, int]]
    column: int = 0

    def __post_init__(self) -> None:
        self.column = self.ops[0][1]

    def evaluate(self, board: BlackboardLike) -> bool:
        lhs_node = self.operands[0]
        lhs = lhs_node.evaluate(board)
        for (op, column), rhs_node in zip(self.ops, self.operands[1:]):
            rhs = rhs_node.evaluate(board)
            result = _compare(op, lhs, rhs)
            if result is None:
                raise ScriptError(
                    f"cannot compare {lhs_node.operand(lhs)} with {rhs_node.operand(rhs)} using '{op}'", column
                )
            if not result:
                return False
            lhs_node, lhs = rhs_node, rhs
        return True


@dataclass
class Ternary(Node):
    condition: Node
    then: Node
    otherwise: Node
    column: int

    def evaluate(self, board: BlackboardLike) -> Any:
        value = self.condition.evaluate(board)
        try:
            named = f" ('{self.condition.name}')" if isinstance(self.condition, Name) else ""
            chosen = truth(value, f"the condition of '?'{named}")
        except ScriptError as err:
            raise ScriptError(err.message, self.column) from None
        return (self.then if chosen else self.otherwise).evaluate(board)


def coerce_for_entry(key: str, current: Any, value: Any) -> Any:
    """``value`` converted to the type ``current`` already has, as BT.CPP's typed entries do.

    An empty entry (None) takes anything. Raises ScriptError when the value does not fit.
    """
    if current is None:
        return value
    if _is_bool(current):
        if _is_bool(value):
            return bool(value)
        if _is_number(value) and value in (0, 1):
            return bool(value)
        if isinstance(value, str) and value.strip() in ("true", "false"):
            return value.strip() == "true"
        raise ScriptError(f"entry '{key}' holds a bool; cannot store {_describe(value)} in it")
    if _is_number(current):
        number: Any = value
        if isinstance(value, str):
            number = _string_as_number(value)
            if number is None:
                raise ScriptError(f"entry '{key}' holds a number; cannot store {_describe(value)} in it")
        elif not _is_number(value):
            raise ScriptError(f"entry '{key}' holds a number; cannot store {_describe(value)} in it")
        if _is_integral(current):
            if not _is_integral(number) and not float(number).is_integer():
                raise ScriptError(
                    f"entry '{key}' holds an integer; storing {_describe(value)} would lose its fraction"
                )
            return int(number)
        return float(number)
    if isinstance(current, str):
        if isinstance(value, str):
            return value
        raise ScriptError(
            f"entry '{key}' holds a string; cannot store {_describe(value)} in it (build a string with '..')"
        )
    if type(value) is type(current):
        return value
    raise ScriptError(f"entry '{key}' holds {_describe(current)}; a script cannot store {_describe(value)} in it")


@dataclass
class Assign(Node):
    """``name := v`` (create or assign), ``name = v`` (must exist), ``name += v`` and friends."""

    target: Name
    op: str
    value: Node
    column: int

    def evaluate(self, board: BlackboardLike) -> Any:
        key = self.target.name
        exists = board.has(key)
        if not exists and self.op != ":=":
            hint = "; use ':=' to create it" if self.op == "=" else ""
            raise ScriptError(f"blackboard entry '{key}' does not exist{hint}", self.target.column)
        value = self.value.evaluate(board)
        if value is None:
            raise ScriptError(f"'{self.op}' has nothing (None) to store in '{key}'", self.column)
        current = board.get(key) if exists else None
        try:
            if self.op in (":=", "="):
                new = coerce_for_entry(key, current, value)
            else:
                new = coerce_for_entry(key, current, self._update(key, current, value))
        except ScriptError as err:
            raise ScriptError(err.message, err.column or self.column) from None
        board.set(key, new)
        return new

    def _update(self, key: str, current: Any, value: Any) -> Any:
        op = self.op[0]
        if current is None:
            raise ScriptError(f"entry '{key}' is empty (None); '{self.op}' needs a value to update", self.column)
        if op == "+" and isinstance(current, str):
            if isinstance(value, str):
                return _joined(current, value, self.column)
            raise ScriptError(f"'+=' on the string entry '{key}' needs a string, got {_describe(value)}", self.column)
        if not (_is_number(current) and _is_number(value)):
            raise ScriptError(
                f"'{self.op}' needs numbers: '{key}' holds {_describe(current)}, the value is {_describe(value)}",
                self.column,
            )
        try:
            return _arithmetic(op, current, value)
        except ZeroDivisionError:
            raise ScriptError(f"division by zero: '{key}' /= {_describe(value)}", self.column) from None


# --------------------------------------------------------------------------------------------
# The parser: precedence climbing, iterative along each level, recursive only into nesting
# --------------------------------------------------------------------------------------------
LOGICAL, COMPARE, CONCAT, BIT_OR, BIT_AND, SUM, PRODUCT = range(1, 8)
_LEVELS = {
    "&&": LOGICAL, "||": LOGICAL,
    "==": COMPARE, "!=": COMPARE, "<": COMPARE, "<=": COMPARE, ">": COMPARE, ">=": COMPARE,
    "..": CONCAT,
    "|": BIT_OR, "^": BIT_OR,
    "&": BIT_AND,
    "+": SUM, "-": SUM,
    "*": PRODUCT, "/": PRODUCT,
}  # fmt: skip
_ASSIGNMENTS = (":=", "=", "+=", "-=", "*=", "/=")
_PREFIXES = ("-", "!", "~")
_WORD_OPERATORS = {"and": "&&", "or": "||", "not": "!"}
_FAMILY_NAMES = {"math": "arithmetic (+ - * / and prefix -)", "bits": "bitwise (& | ^ ~ and !)"}


class _Parser:
    def __init__(self, source: str) -> None:
        self.tokens = tokenize(source)
        self.pos = 0
        self.depth = 0

    # -- helpers ---
    def peek(self) -> Token:
        return self.tokens[self.pos]

    def advance(self) -> Token:
        token = self.tokens[self.pos]
        self.pos += 1
        return token

    def is_op(self, *texts: str) -> bool:
        token = self.peek()
        return token.kind == "op" and token.text in texts

    def unexpected(self, expected: str) -> ScriptError:
        token = self.peek()
        if token.kind == "name" and token.text in _WORD_OPERATORS:
            return ScriptError(
                f"'{token.text}' is not an operator in BT.CPP scripts; write '{_WORD_OPERATORS[token.text]}'",
                token.column,
            )
        return ScriptError(f"unexpected {_describe_token(token)}; expected {expected}", token.column)

    def enter(self, column: int) -> None:
        self.depth += 1
        if self.depth > MAX_DEPTH:
            raise ScriptError(f"expression nested too deeply (more than {MAX_DEPTH} levels)", column)

    # -- grammar ---
    def script(self) -> list[Node]:
        statements: list[Node] = []
        while self.peek().kind != "end":
            statements.append(self.expression())
            if self.is_op(";"):
                self.advance()
            elif self.peek().kind != "end":
                raise self.unexpected("an operator, or ';' between statements")
        if not statements:
            raise ScriptError("empty script", 1)
        return statements

    def expression(self, assignable: bool = True) -> Node:
        """A full expression: ``condition ? a : b``, optionally assigned to an entry.

        Ternary and assignment share this function (and ``operand`` holds prefixes and atoms) so
        each level of nesting costs three Python frames: 200 levels stay far from the
        interpreter's recursion limit.
        """
        node = self.binary(LOGICAL)
        if self.is_op("?"):
            question = self.advance()
            self.enter(question.column)
            then = self.expression()
            self.depth -= 1
            if not self.is_op(":"):
                raise self.unexpected(f"':' to go with the '?' from column {question.column}")
            self.advance()
            otherwise = self.binary(LOGICAL)
            if self.is_op("?"):
                raise ScriptError("'?' cannot be chained; put the inner one in parentheses", self.peek().column)
            node = Ternary(node, then, otherwise, question.column)
        if self.is_op(*_ASSIGNMENTS):
            op = self.advance()
            if not assignable:
                raise ScriptError(
                    "assignments cannot be chained; write one per statement, separated by ';'", op.column
                )
            if not isinstance(node, Name):
                raise ScriptError(f"the left side of '{op.text}' must be a blackboard entry name", op.column)
            node = Assign(node, op.text, self.expression(assignable=False), op.column)
        return node

    def binary(self, min_level: int) -> Node:
        """Operators of ``min_level`` and tighter, left to right."""
        left = self.operand()
        while True:
            token = self.peek()
            level = _LEVELS.get(token.text) if token.kind == "op" else None
            if level is None or level < min_level:
                return left
            self.enter(token.column)
            if level == COMPARE:
                operands, ops = [left], []
                while self.is_op("==", "!=", "<", "<=", ">", ">="):
                    op = self.advance()
                    ops.append((op.text, op.column))
                    operands.append(self.binary(COMPARE + 1))
                left = Compare(operands, ops)
            else:
                self.advance()
                left = self.combine(left, token, level, self.binary(level + 1))
            self.depth -= 1

    def combine(self, left: Node, op: Token, level: int, right: Node) -> Node:
        family = "math" if level >= SUM else "bits" if level >= BIT_OR else None
        if family is not None:
            for side in (left, right):
                if side.family is not None and side.family != family:
                    raise ScriptError(
                        f"'{op.text}' cannot be mixed with {_FAMILY_NAMES[side.family]} operators "
                        "without parentheses",
                        op.column,
                    )
        if isinstance(left, Chain) and left.level == level:
            left.operands.append(right)
            left.ops.append((op.text, op.column))
            return left
        return Chain(level, [left, right], [(op.text, op.column)])

    def operand(self) -> Node:
        """Prefix operators, then a value or a parenthesized expression."""
        prefixes: list[Token] = []
        while self.is_op(*_PREFIXES):
            prefixes.append(self.advance())
            self.enter(prefixes[-1].column)
        token = self.peek()
        node: Node
        if token.kind in ("number", "string", "bool"):
            self.advance()
            node = Literal(token.value, token.column)
        elif token.kind == "name" and token.text not in _WORD_OPERATORS:
            self.advance()
            node = Name(token.text, token.column)
        elif self.is_op("("):
            self.advance()
            self.enter(token.column)
            node = Group(self.expression(), token.column)
            self.depth -= 1
            if self.peek().kind == "end":
                raise ScriptError("'(' is never closed", token.column)
            if not self.is_op(")"):
                raise self.unexpected(f"')' to close the '(' from column {token.column}")
            self.advance()
        else:
            raise self.unexpected("a value (a number, a 'string', true/false, an entry name or '(')")
        for op in reversed(prefixes):
            wrapped = Unary(op.text, node, op.column)
            if node.family is not None and node.family != wrapped.family:
                raise ScriptError(
                    f"'{op.text}' cannot be applied to {_FAMILY_NAMES[node.family]} operators "
                    "without parentheses",
                    op.column,
                )
            node = wrapped
        self.depth -= len(prefixes)
        return node


# --------------------------------------------------------------------------------------------
# Public API
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Script:
    """A parsed script; evaluate it as often as needed (each tick, each precondition check)."""

    source: str
    statements: tuple[Node, ...] = field(repr=False)

    def evaluate(self, blackboard: BlackboardLike) -> Any:
        """Run every statement in order and return the value of the last one.

        Raises ScriptError naming the entry or operation that failed, with its column. Statements
        before the failing one have already written their entries (as in BT.CPP).
        """
        result: Any = None
        try:
            for statement in self.statements:
                result = statement.evaluate(blackboard)
        except RecursionError:
            raise ScriptError("script nested too deeply to evaluate") from None
        return result


def compile_script(source: str) -> Script:
    """Parse ``source`` once; raises ScriptError with the column of the first syntax error."""
    if not isinstance(source, str):
        raise ScriptError(f"a script must be text, got {type(source).__name__}")
    if len(source) > MAX_SOURCE_CHARS:
        raise ScriptError(f"script is {len(source)} characters long; the limit is {MAX_SOURCE_CHARS}")
    try:
        statements = _Parser(source).script()
    except RecursionError:
        raise ScriptError(f"expression nested too deeply (more than {MAX_DEPTH} levels)") from None
    return Script(source, tuple(statements))


def evaluate_condition(script: Script | str, blackboard: BlackboardLike) -> bool:
    """Run ``script`` and read its value as BT.CPP reads a condition.

    True/false, a non-zero number, or the strings 'true'/'false'; any other value raises
    ScriptError (so ``_skipIf="name"`` on a string entry is reported, not taken as true).
    """
    compiled = compile_script(script) if isinstance(script, str) else script
    value = compiled.evaluate(blackboard)
    return truth(value, f"the condition {compiled.source.strip()!r}")
