"""The script language (runtime.tree.script) and the script leaves (runtime.tree.script_nodes).

Where BT.CPP and this runtime should agree, the same script also runs in BehaviorTree.CPP 4.8
through behaviortreepy and the blackboard values are compared.
"""
from __future__ import annotations

from xml.sax.saxutils import quoteattr

import pytest

from runtime.tree.behavior import RunContext, Status
from runtime.tree.blackboard import Blackboard
from runtime.io.bus import InProcessBus
from runtime.io.clock import SimClock
from runtime.errors import LoadError, PortError, ScriptRunError, SourceLocation
from runtime.tree.events import EventLog
from runtime.tree.registry import Registry
from runtime.tree.script import MAX_DEPTH, MAX_SOURCE_CHARS, MAX_STRING_CHARS, ScriptError, compile_script, evaluate_condition
from runtime.tree.script_nodes import NODES, Script, ScriptCondition, SetBlackboard, compile_at_load


def run(source: str, board: Blackboard | None = None, **entries) -> object:
    board = board if board is not None else Blackboard()
    for key, value in entries.items():
        board.set(key, value)
    return compile_script(source).evaluate(board)


def error_of(source: str, board: Blackboard | None = None, **entries) -> ScriptError:
    with pytest.raises(ScriptError) as info:
        run(source, board, **entries)
    return info.value


# --------------------------------------------------------------------------------------------
# Values and operators
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "source, expected",
    [
        ("1 + 2 * 3", 7.0),
        ("(1 + 2) * 3", 9.0),
        ("10 - 2 - 3", 5.0),  # left to right (BT.CPP <= 4.8 said 11: its bug #1029)
        ("8 / 2 / 2", 2.0),
        ("-2 * 3", -6.0),
        ("- -2", 2.0),
        ("10 / 4", 2.5),
        ("2 * 3 - 1", 5.0),
        ("0x10 + 1", 17.0),
        ("1e3", 1000.0),
        ("1.5e-1 * 2", 0.3),
        ("5 ^ 1", 4),
        ("1 | 2", 3),
        ("6 & 3", 2),
        ("~0", -1),
    ],
)
def test_arithmetic_precedence_and_literals(source, expected):
    assert run(source) == pytest.approx(expected)


def test_integer_literals_stay_integers_until_an_operator_touches_them():
    assert run("42") == 42 and isinstance(run("42"), int)
    assert isinstance(run("40 + 2"), float)  # BT.CPP computes in doubles
    assert run("true") is True and run("false") is False


@pytest.mark.parametrize(
    "source, expected",
    [
        ("1 || 0 && 0", False),  # && and || are one level, left to right (BT.CPP)
        ("0 && 0 || 1", True),
        ("!0", True),
        ("!!2", True),
        ("1 < 2 < 3", True),
        ("3 > 2 > 1", True),  # a chain: 3 > 2 and 2 > 1
        ("1 < 3 < 2", False),
        ("1 == 1.0", True),
        ("0.1 + 0.2 == 0.3", True),  # float epsilon, as BT.CPP
        ("1 != 1.0000001", False),
        ("2 >= 2 && 2 <= 2", True),
        ("'abc' < 'abd'", True),
        ("'a' == 'a'", True),
        ("true == 1", True),
    ],
)
def test_logic_and_comparisons(source, expected):
    assert run(source) is expected


def test_strings_holding_numbers_compare_numerically_with_numbers():
    assert run("n == 42", n="42") is True
    assert run("n > 4.5", n="42") is True
    assert run("n < 100", n=" 7.5 ") is True
    assert run("flag == 1", flag="true") is True
    err = error_of("name == 3", name="abc")
    assert err.message == "cannot compare 'name' (the string 'abc') with 3 using '=='"
    assert err.column == 6


def test_string_concatenation():
    assert run("'x' .. 'y'") == "xy"
    assert run("'n=' .. 3") == "n=3"
    assert run("'v=' .. 2.5") == "v=2.500000"  # as BT.CPP writes a double
    assert run("'sum=' .. 1 + 2") == "sum=3.000000"  # '..' binds looser than arithmetic
    assert run("'a' + 'b'") == "ab"
    assert run("name .. '!'", name="hi") == "hi!"
    assert run("'ok=' .. (1 < 2)") == "ok=true"
    assert run("'a' .. 'b' == 'ab'") is True


def test_ternary():
    assert run("1 ? 'yes' : 'no'") == "yes"
    assert run("x > 3 ? x : 3", x=5) == 5
    assert run("x > 3 ? x : 3", x=1) == 3
    assert run("c ? 1 : 2", c="false") == 2
    assert run("1 ? (0 ? 'a' : 'b') : 'c'") == "b"
    err = error_of("c ? 1 : 2", c="maybe")
    assert err.message == "the condition of '?' ('c') gave the string 'maybe', which is neither true nor false"
    assert err.column == 3


def test_statements_run_in_order_and_the_last_value_is_returned():
    board = Blackboard()
    assert run("a := 1; b := a + 1; b * 10", board) == 20.0
    assert board.get("a") == 1 and board.get("b") == 2.0
    assert run("a := 5;", board) == 5  # a trailing ';' is fine


def test_root_entries_with_at():
    root = Blackboard()
    child = Blackboard(parent=root)
    run("@goal := 'home'", child)
    assert root.get("goal") == "home" and not child.has("goal")
    assert run("@goal .. '!'", child) == "home!"


def test_newlines_and_tabs_are_whitespace():
    assert run("a := 1;\n\tb := a +\n 2; b") == 3.0


# --------------------------------------------------------------------------------------------
# Assignment
# --------------------------------------------------------------------------------------------
def test_create_assign_creates_and_assign_requires_an_existing_entry():
    board = Blackboard()
    assert run("target := 'cube'", board) == "cube"
    assert run("target = 'tray'", board) == "tray"
    assert board.get("target") == "tray"
    err = error_of("missing = 1", board)
    assert err.message == "blackboard entry 'missing' does not exist; use ':=' to create it"
    assert err.column == 1
    assert not board.has("missing")


def test_reading_a_missing_or_empty_entry_names_it():
    err = error_of("x := speed * 2")
    assert (err.message, err.column) == ("blackboard entry 'speed' does not exist", 6)
    err = error_of("speed + 1", speed=None)
    assert err.message == "blackboard entry 'speed' is empty (None)"


def test_assignment_keeps_the_type_of_the_entry():
    board = Blackboard()
    run("count := 0; count = count + 1; count += 1", board)
    assert board.get("count") == 2 and isinstance(board.get("count"), int)
    run("count = '7'", board)
    assert board.get("count") == 7
    err = error_of("count = 2.5", board)
    assert err.message == "entry 'count' holds an integer; storing 2.5 would lose its fraction"
    assert err.column == 7
    run("ratio := 0.5; ratio = 2", board)
    assert board.get("ratio") == 2.0 and isinstance(board.get("ratio"), float)
    err = error_of("label := 'a'; label = 3", board)
    assert err.message == "entry 'label' holds a string; cannot store 3 in it (build a string with '..')"
    run("flag := true; flag = 0", board)
    assert board.get("flag") is False
    assert "holds a bool" in error_of("flag = 5", board).message


def test_compound_assignment():
    board = Blackboard()
    run("n := 10; n -= 4; n *= 2", board)
    assert board.get("n") == 12
    run("d := 1.0; d /= 4", board)
    assert board.get("d") == 0.25
    run("s := 'ab'; s += 'c'", board)
    assert board.get("s") == "abc"
    assert "'+=' on the string entry 's' needs a string, got 1" in error_of("s += 1", board).message
    assert error_of("nope += 1", board).message == "blackboard entry 'nope' does not exist"
    assert error_of("n /= 0", board).message.startswith("division by zero")


def test_statements_before_a_failing_one_have_written():
    board = Blackboard()
    error_of("a := 1; b = 2", board)
    assert board.get("a") == 1


# --------------------------------------------------------------------------------------------
# Errors at evaluation
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "source, entries, message, column",
    [
        ("x + 1", {"x": "abc"}, "cannot apply '+' to 'x' (the string 'abc') and 1", 3),
        ("1 / (2 - 2)", {}, "division by zero: 1 / 0.0", 3),
        ("-s", {"s": "a"}, "'-' needs a number, got 's' (the string 'a')", 1),
        ("1.5 & 1", {}, "'&' needs two integers, got 1.5 and 1", 5),
        ("s && 1", {"s": "yes"}, "'&&' needs true/false or numbers, got 's' (the string 'yes') (compare strings with '==' first)", 3),
        ("p == 1", {"p": [1, 2]}, "cannot compare 'p' (a list) with 1 using '=='", 3),
    ],
)
def test_evaluation_errors_name_the_entry_and_operation(source, entries, message, column):
    err = error_of(source, **entries)
    assert (err.message, err.column) == (message, column)
    assert str(err) == f"{message} at column {column}"


def test_logical_operators_evaluate_both_sides_like_btcpp():
    # BT.CPP does not short-circuit: a missing entry is reported even when the left side decides.
    assert error_of("1 || missing").message == "blackboard entry 'missing' does not exist"


# --------------------------------------------------------------------------------------------
# Syntax errors (raised by compile_script, at load time)
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "source, message, column",
    [
        ("a := 1)", "unexpected ')'; expected an operator, or ';' between statements", 7),
        ("a := (1 + 2", "'(' is never closed", 6),
        ("a := (1 + 2 3)", "unexpected 3; expected ')' to close the '(' from column 6", 13),
        ("a := 'abc", "unterminated string (the ' is never closed)", 6),
        ("a := 1 +", "unexpected end of script; expected a value (a number, a 'string', true/false, an entry name or '(')", 9),
        ("a := 7 and 1", "'and' is not an operator in BT.CPP scripts; write '&&'", 8),
        ("not a", "'not' is not an operator in BT.CPP scripts; write '!'", 1),
        ("!a + 1", "'+' cannot be mixed with bitwise (& | ^ ~ and !) operators without parentheses", 4),
        ("a + 1 & 2", "'&' cannot be mixed with arithmetic (+ - * / and prefix -) operators without parentheses", 7),
        ("1 ? 2 : 3 ? 4 : 5", "'?' cannot be chained; put the inner one in parentheses", 11),
        ("1 ? 2 3", "unexpected 3; expected ':' to go with the '?' from column 3", 7),
        ("a := b := 1", "assignments cannot be chained; write one per statement, separated by ';'", 8),
        ("1 := 2", "the left side of ':=' must be a blackboard entry name", 3),
        ("a := 1;; b := 2", "unexpected ';'; expected a value (a number, a 'string', true/false, an entry name or '(')", 8),
        ("a := 12ab", "invalid number '12ab'", 6),
        ("a := 1.5.2", "invalid number '1.5.2'", 6),
        ("a := #", "unexpected character '#'", 6),
        ("@ := 1", "'@' must be followed by an entry name", 1),
        ("", "empty script", 1),
        ("   ", "empty script", 1),
    ],
)
def test_syntax_errors_have_a_message_and_a_column(source, message, column):
    with pytest.raises(ScriptError) as info:
        compile_script(source)
    assert (info.value.message, info.value.column) == (message, column)


def test_depth_is_bounded():
    deepest = "(" * MAX_DEPTH + "1" + ")" * MAX_DEPTH
    assert compile_script(deepest).evaluate(Blackboard()) == 1
    with pytest.raises(ScriptError, match=rf"expression nested too deeply \(more than {MAX_DEPTH} levels\)"):
        compile_script("(" + deepest + ")")
    with pytest.raises(ScriptError, match="nested too deeply"):
        compile_script("-" * (MAX_DEPTH + 1) + "1")
    with pytest.raises(ScriptError, match="nested too deeply"):
        compile_script("1" + "+(1" * 400 + ")" * 400)


def test_long_flat_chains_are_fine_and_length_is_bounded():
    chain = "1" + " + 1" * 2000
    assert compile_script(chain).evaluate(Blackboard()) == 2001.0
    with pytest.raises(ScriptError) as info:
        compile_script("1" + " " * MAX_SOURCE_CHARS)
    assert info.value.message == f"script is {MAX_SOURCE_CHARS + 1} characters long; the limit is {MAX_SOURCE_CHARS}"


def test_a_script_is_compiled_once_and_evaluated_many_times():
    script = compile_script("n := n + 1")
    board = Blackboard()
    board.set("n", 0)
    for _ in range(3):
        script.evaluate(board)
    assert board.get("n") == 3
    assert script.source == "n := n + 1"


# --------------------------------------------------------------------------------------------
# Conditions
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "source, entries, expected",
    [
        ("true", {}, True),
        ("false", {}, False),
        ("x > 3", {"x": 4}, True),
        ("x", {"x": 2.5}, True),
        ("x", {"x": 0}, False),
        ("flag", {"flag": "true"}, True),
        ("flag", {"flag": "False"}, False),
        ("done && tries < 3", {"done": True, "tries": 2}, True),
    ],
)
def test_evaluate_condition(source, entries, expected):
    board = Blackboard()
    for key, value in entries.items():
        board.set(key, value)
    assert evaluate_condition(compile_script(source), board) is expected
    assert evaluate_condition(source, board) is expected  # source text is compiled on the spot


def test_a_condition_that_is_a_string_is_an_error():
    board = Blackboard()
    board.set("name", "cube")
    with pytest.raises(ScriptError) as info:
        evaluate_condition("name", board)
    assert info.value.message == "the condition 'name' gave the string 'cube', which is neither true nor false"


# --------------------------------------------------------------------------------------------
# The nodes
# --------------------------------------------------------------------------------------------
HERE = SourceLocation("objectives/check.xml", 12)


@pytest.fixture
def context() -> RunContext:
    clock = SimClock()
    return RunContext(clock=clock, bus=InProcessBus(clock), events=EventLog(clock))


def bound(cls, context, board, **values):
    node = cls(cls.__name__)
    node.bind(context, board, values, HERE, cls.__name__)
    return node


def tick(node) -> Status:
    node.tick_once()
    return node.status


def test_script_node_runs_its_code_each_tick(context):
    board = Blackboard()
    board.set("count", 0)
    node = bound(Script, context, board, code="count += 1; msg := 'tick ' .. count")
    assert tick(node) is Status.SUCCESS
    assert tick(node) is Status.SUCCESS
    assert board.get("count") == 2
    assert board.get("msg") == "tick 2"


def test_a_failing_script_is_a_run_error_naming_file_line_node_and_script(context):
    board = Blackboard()
    node = bound(Script, context, board, code="speed = 2")
    with pytest.raises(ScriptRunError) as info:
        tick(node)
    assert str(info.value) == (
        "objectives/check.xml:12: Script 'Script': script 'speed = 2': "
        "blackboard entry 'speed' does not exist; use ':=' to create it at column 1"
    )
    assert info.value.script == "speed = 2"


def test_script_syntax_errors_stop_the_load_with_file_line_node_and_column(context):
    with pytest.raises(LoadError) as info:
        bound(Script, context, Blackboard(), code="a := (1 + 2")
    assert str(info.value) == (
        "objectives/check.xml:12: Script: port 'code': '(' is never closed at column 6 in script 'a := (1 + 2'"
    )
    with pytest.raises(LoadError, match="'and' is not an operator"):
        bound(ScriptCondition, context, Blackboard(), code="a and b")


def test_code_must_be_literal_and_present(context):
    with pytest.raises(LoadError, match=r"port 'code' must be the script itself, not a blackboard reference '\{src\}'"):
        bound(Script, context, Blackboard(), code="{src}")
    with pytest.raises(PortError, match="missing required port 'code'"):
        bound(Script, context, Blackboard())


def test_compile_at_load_names_the_attribute():
    with pytest.raises(LoadError) as info:
        compile_at_load("x ==", HERE, "MoveTo", where="attribute '_skipIf'")
    assert str(info.value).startswith("objectives/check.xml:12: MoveTo: attribute '_skipIf': unexpected end of script")
    assert compile_at_load("x == 1", HERE, "MoveTo").source == "x == 1"


def test_script_condition(context):
    board = Blackboard()
    board.set("height", 0.12)
    node = bound(ScriptCondition, context, board, code="height > 0.1")
    assert tick(node) is Status.SUCCESS
    board.set("height", 0.05)
    assert tick(node) is Status.FAILURE
    assert node.feedback_message == "'height > 0.1' is false"
    board.set("height", "tall")
    with pytest.raises(ScriptRunError, match=(
        r"script 'height > 0.1': cannot compare 'height' \(the string 'tall'\) with 0.1 using '>' at column 8"
    )):
        tick(node)


def test_set_blackboard_writes_a_string_or_converts_to_the_entry_type(context):
    board = Blackboard()
    assert tick(bound(SetBlackboard, context, board, value="42", output_key="answer")) is Status.SUCCESS
    assert board.get("answer") == "42"  # a literal is a string, as in BT.CPP
    board.set("tries", 3)
    assert tick(bound(SetBlackboard, context, board, value="7", output_key="tries")) is Status.SUCCESS
    assert board.get("tries") == 7
    node = bound(SetBlackboard, context, board, value="many", output_key="tries")
    with pytest.raises(ScriptRunError) as info:  # BT.CPP throws: an entry keeps its type
        tick(node)
    assert str(info.value) == (
        "objectives/check.xml:12: SetBlackboard 'SetBlackboard': value 'many': "
        "entry 'tries' holds a number; cannot store the string 'many' in it"
    )


def test_set_blackboard_copies_an_entry_with_its_type(context):
    board = Blackboard()
    board.set("pose", [0.1, 0.2, 0.3])
    assert tick(bound(SetBlackboard, context, board, value="{pose}", output_key="{goal}")) is Status.SUCCESS
    assert board.get("goal") == [0.1, 0.2, 0.3]
    node = bound(SetBlackboard, context, board, value="{nowhere}", output_key="goal")
    assert board.has("nowhere")  # declared when the node was bound, as BT.CPP does; no value yet
    assert tick(node) is Status.FAILURE  # BT.CPP: an empty source fails
    assert node.feedback_message == "port 'value' reads blackboard entry 'nowhere', which is empty"
    board.unset("nowhere")
    with pytest.raises(ScriptRunError, match="port 'value' reads blackboard entry 'nowhere', which does not exist"):
        tick(node)


def test_nodes_are_registered():
    registry = Registry()
    registry.register_all(NODES)
    assert [s.id for s in registry.specs()] == ["Script", "ScriptCondition", "SetBlackboard", "UnsetBlackboard"]
    assert registry.get("ScriptCondition").kind.value == "Condition"


# --------------------------------------------------------------------------------------------
# Cross-check against BehaviorTree.CPP (behaviortreepy)
# --------------------------------------------------------------------------------------------
def btcpp_run(code: str, node: str = "Script", **entries):
    """Tick a one-node BT.CPP tree; returns (status name or 'error', blackboard)."""
    import behaviortreepy as bt  # a test dependency: missing, the test fails
    board = bt.Blackboard.create()
    for key, value in entries.items():
        if isinstance(value, bool):
            board.set_bool(key, value)
        elif isinstance(value, int):
            board.set_int(key, value)
        elif isinstance(value, float):
            board.set_double(key, value)
        else:
            board.set_string(key, value)
    xml = f'<root BTCPP_format="4"><BehaviorTree ID="Main"><{node} code={quoteattr(code)}/></BehaviorTree></root>'
    try:
        tree = bt.BehaviorTreeFactory().create_tree_from_text(xml, board)
        status = tree.tick_once().name
    except RuntimeError:
        return "error", board
    return status, board


@pytest.mark.parametrize(
    "code",
    [
        "r := 1 + 2 * 3",
        "r := (1 + 2) * 3",
        "r := 10 / 4",
        "r := -2 * 3",
        "r := 2 * 3 - 1",
        "r := 1 || 0 && 0",
        "r := 0 && 0 || 1",
        "r := 3 > 2 > 1",
        "r := 0.1 + 0.2 == 0.3",
        "r := 'abc' < 'abd'",
        "r := 5 ^ 1",
        "r := 1 | 2",
        "r := ~0",
        "r := !0",
        "r := 0x10",
        "r := 1 ? 4 : 5",
        "r := n == 42",
        "r := i; r += 2",
    ],
)
def test_numbers_match_btcpp(code):
    entries = {"n": "42", "i": 3}
    status, bt_board = btcpp_run(code, **entries)
    assert status == "SUCCESS"
    ours = Blackboard()
    for key, value in entries.items():
        ours.set(key, value)
    compile_script(code).evaluate(ours)
    assert float(ours.get("r")) == pytest.approx(bt_board.get_double("r"))


@pytest.mark.parametrize(
    "code, expected",
    [
        ("r := 'x' .. 'y'", "xy"),
        ("r := 'n=' .. 3", "n=3"),
        ("r := 'a' + 'b'", "ab"),
        ("r := 1 ? 'yes' : 'no'", "yes"),
        ("r := s .. '!'", "hi!"),
        ("r := 'x=' .. 2.5", "x=2.500000"),
        ("r := 'x=' .. d", "x=2.500000"),
        ("r := 'x=' .. (1 + 2)", "x=3.000000"),
        ("r := 'x=' .. (0 - 1e-9)", "x=-0.000000"),
        ("r := 'x=' .. 123456789.125", "x=123456789.125000"),
        ("r := 'x=' .. i", "x=7"),
    ],
)
def test_strings_match_btcpp(code, expected):
    status, bt_board = btcpp_run(code, s="hi", d=2.5, i=7)
    assert status == "SUCCESS"
    assert bt_board.get_string("r") == expected
    assert run(code, s="hi", d=2.5, i=7) == expected


@pytest.mark.parametrize("doubling", ["s = s .. s", "s = s + s", "s += s"])
def test_a_string_doubled_past_the_limit_is_an_error_not_a_full_memory(doubling):
    """On main a script doubling a string reached 6.9 GB."""
    script = "s := 'ab'; " + "; ".join([doubling] * 20)  # the 19th doubling makes 2^20 characters
    with pytest.raises(ScriptError, match=rf"^the string would be 1048576 characters long; scripts build strings of at most {MAX_STRING_CHARS} at column \d+$"):
        run(script)
    assert len(run("s := 'ab'; " + "; ".join([doubling] * 18))) == 2**19  # below the limit


def test_integer_entries_stay_integers_in_both():
    status, bt_board = btcpp_run("c := 0; c += 1; c = c + 1")
    assert status == "SUCCESS" and bt_board.get_string("c") == "2"  # BT.CPP writes doubles as 2.000000
    board = Blackboard()
    run("c := 0; c += 1; c = c + 1", board)
    assert board.get("c") == 2 and isinstance(board.get("c"), int)


@pytest.mark.parametrize(
    "code",
    [
        "b = 2",  # '=' needs an existing entry
        "i := 3; i = 2.5",  # an integer entry refuses a fraction
        "s := 'x'; s = 3",  # a string entry refuses a number
        "r := 'abc' == 3",  # a non-numeric string does not compare with a number
        "r := s + 1",  # no arithmetic on strings
        "r := !1 + 1",  # bitwise and arithmetic do not mix
        "r := 1 ? 2 : 3 ? 4 : 5",  # the ternary does not chain
        "r := 7 and 1",  # no word operators
        "r := (1 + ",
    ],
)
def test_errors_match_btcpp(code):
    status, _ = btcpp_run(code, s="hi")
    assert status == "error"
    with pytest.raises(ScriptError):
        run(code, s="hi")


@pytest.mark.parametrize(
    "code, entries",
    [
        ("x > 3", {"x": 4}),
        ("x > 3", {"x": 2}),
        ("x == 'go' && y < 1.5", {"x": "go", "y": 1.0}),
        ("x == 'go' && y < 1.5", {"x": "stop", "y": 1.0}),
        ("n == 42", {"n": "42"}),
    ],
)
def test_script_condition_matches_btcpp(code, entries, context):
    status, _ = btcpp_run(code, node="ScriptCondition", **entries)
    board = Blackboard()
    for key, value in entries.items():
        board.set(key, value)
    node = bound(ScriptCondition, context, board, code=code)
    assert tick(node).name == status


def test_an_integer_literal_past_64_bits_is_refused_as_bt_cpp_refuses_it():
    """On main a 5,000-digit literal ended as an internal error (Python's int-to-text limit)."""
    assert btcpp_run("x := 9223372036854775807")[0] == "SUCCESS" and btcpp_run("x := 9223372036854775808")[0] == "error"
    run("x := 9223372036854775807")
    with pytest.raises(ScriptError, match=r"^integer 9223372036854775808 is too large: a script's integers are 64-bit "
                                          r"\(at most 9223372036854775807\) at column 6$"):
        run("x := 9223372036854775808")
    with pytest.raises(ScriptError, match=r"^integer 99999999999999999999\.\.\. \(5000 characters\) is too large"):
        run("x := " + "9" * 5000)
    with pytest.raises(ScriptError, match=r"^integer 0x1ffffffffffffffff is too large"):
        run("x := 0x1ffffffffffffffff")
