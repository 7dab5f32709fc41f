"""The XML loader: both syntaxes, SubTrees and their blackboards, libraries, safe parsing, errors."""
from __future__ import annotations

from pathlib import Path

import pytest

from runtime.tree.behavior import NodeKind, Status
from runtime.tree.controls import tick_tree
from runtime.errors import LoadError, ObjectiveError, PortError
from runtime.tree.loader import LoadedTree, load_tree, throwaway_context, validate
from runtime.tree.subtree import SubTree
from tests.data.nodes import make_registry

DATA = Path(__file__).parent / "data"


@pytest.fixture(scope="module")
def registry():
    return make_registry()


@pytest.fixture
def empty_lib(tmp_path):
    """An empty objectives directory, so tests do not depend on the shipped Objectives."""
    lib = tmp_path / "emptylib"
    lib.mkdir()
    return lib


def write(tmp_path: Path, text: str, name: str = "tree.xml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def load(registry, path, empty_lib, **kwargs) -> LoadedTree:
    kwargs.setdefault("objectives_dir", empty_lib)
    return load_tree(path, registry, throwaway_context(), **kwargs)


def run_to_end(tree: LoadedTree, limit: int = 1000) -> Status:
    context = tree.nodes[0].node.context
    for _ in range(limit):
        context.clock.advance(0.01)
        status = tick_tree(tree.root).status
        if status is not Status.RUNNING:
            return status
    raise AssertionError("tree did not finish")


def error_of(registry, path, empty_lib, **kwargs) -> str:
    with pytest.raises(ObjectiveError) as info:
        load(registry, path, empty_lib, **kwargs)
    return str(info.value)


# -- syntax ------------------------------------------------------------------------------------
def test_explicit_and_compact_syntax_build_the_same_tree(registry, tmp_path, empty_lib):
    explicit = write(tmp_path, """<root BTCPP_format="4">
  <BehaviorTree ID="T">
    <Control ID="Sequence" name="main">
      <Decorator ID="Inverter"><Action ID="AlwaysFailure"/></Decorator>
      <Action ID="Typed" x="2" out="{y}"/>
      <Condition ID="Check" value="true"/>
    </Control>
  </BehaviorTree>
</root>""", "explicit.xml")
    compact = write(tmp_path, """<root BTCPP_format="4">
  <BehaviorTree ID="T">
    <Sequence name="main">
      <Inverter><AlwaysFailure/></Inverter>
      <Typed x="2" out="{y}"/>
      <Check value="true"/>
    </Sequence>
  </BehaviorTree>
</root>""", "compact.xml")
    shapes = []
    for path in (explicit, compact):
        tree = load(registry, path, empty_lib)
        shapes.append([(n.xml_id, n.node.name, n.kind, n.location.line) for n in tree.nodes])
        assert run_to_end(tree) is Status.SUCCESS
        assert tree.blackboard.get("y") == 6.0
    assert shapes[0] == shapes[1]
    assert shapes[0][0] == ("Sequence", "main", NodeKind.CONTROL, 3)
    assert [s[0] for s in shapes[0]] == ["Sequence", "Inverter", "AlwaysFailure", "Typed", "Check"]


def test_metadata_attributes_are_accepted_and_name_is_the_display_name(registry, tmp_path, empty_lib):
    path = write(tmp_path, """<root BTCPP_format="4" main_tree_to_execute="T">
  <BehaviorTree ID="T" _description="d" _favorite="true">
    <AlwaysSuccess name="Say yes" _description="x" _favorite="false" _collapsed="true" _uid="7" _fullpath="a/b"/>
  </BehaviorTree>
</root>""")
    tree = load(registry, path, empty_lib)
    assert tree.root.name == "Say yes"
    assert tree.root.xml_id == "AlwaysSuccess"


def test_main_tree_to_execute_and_tree_override(registry, tmp_path, empty_lib):
    path = write(tmp_path, """<root BTCPP_format="4" main_tree_to_execute="B">
  <BehaviorTree ID="A"><AlwaysFailure/></BehaviorTree>
  <BehaviorTree ID="B"><AlwaysSuccess/></BehaviorTree>
</root>""")
    assert load(registry, path, empty_lib).tree_id == "B"
    assert load(registry, path, empty_lib).root.xml_id == "AlwaysSuccess"
    chosen = load(registry, path, empty_lib, tree_id="A")
    assert (chosen.tree_id, chosen.root.xml_id) == ("A", "AlwaysFailure")
    assert error_of(registry, path, empty_lib, tree_id="C") == (
        f"{path}: --tree names BehaviorTree 'C', which is not defined (trees: A, B)"
    )


def test_several_top_level_trees_without_main_is_an_error(registry, tmp_path, empty_lib):
    path = write(tmp_path, """<root BTCPP_format="4">
  <BehaviorTree ID="A"><AlwaysFailure/></BehaviorTree>
  <BehaviorTree ID="B"><AlwaysSuccess/></BehaviorTree>
  <BehaviorTree ID="C"><SubTree ID="B"/></BehaviorTree>
</root>""")
    assert error_of(registry, path, empty_lib) == (
        f"{path}: several BehaviorTrees (A, C) are not used as a SubTree by another and there is no "
        "main_tree_to_execute: name the one to run with main_tree_to_execute or --tree"
    )


def test_without_main_the_tree_no_other_uses_runs(registry, tmp_path, empty_lib):
    """Groot2 drops main_tree_to_execute when it saves: the one tree nothing uses is the main one."""
    path = write(tmp_path, """<root BTCPP_format="4">
  <BehaviorTree ID="Leaf"><AlwaysSuccess/></BehaviorTree>
  <BehaviorTree ID="Middle"><SubTree ID="Leaf" _external="true"/></BehaviorTree>
  <BehaviorTree ID="Top"><Sequence><SubTree ID="Middle"/><SubTree ID="Leaf"/></Sequence></BehaviorTree>
</root>""")
    assert load(registry, path, empty_lib).tree_id == "Top"


def test_a_single_tree_without_id_runs(registry, tmp_path, empty_lib):
    """BT.CPP names ID-less trees BehaviorTree_0, BehaviorTree_1, ... (its own tests write them)."""
    path = write(tmp_path, """<root BTCPP_format="4">
  <BehaviorTree><Script code="ran := 1"/></BehaviorTree>
</root>""")
    tree = load(registry, path, empty_lib)
    assert tree.tree_id == "BehaviorTree_0"
    assert run_to_end(tree) is Status.SUCCESS and tree.blackboard.get("ran") == 1


def test_xml_text_source(registry, empty_lib):
    tree = load(registry, '<root BTCPP_format="4"><BehaviorTree ID="T"><AlwaysSuccess/></BehaviorTree></root>', empty_lib)
    assert tree.file is None and tree.root.xml_id == "AlwaysSuccess"


# -- errors point at file, line and node -------------------------------------------------------
def test_unknown_node_suggests_the_closest_names(registry, tmp_path, empty_lib):
    path = write(tmp_path, """<root BTCPP_format="4">
  <BehaviorTree ID="T">
    <Sequence>
      <Sequense/>
    </Sequence>
  </BehaviorTree>
</root>""")
    assert error_of(registry, path, empty_lib) == f"{path}:4: Sequense: unknown node 'Sequense'; did you mean 'Sequence' or 'AsyncSequence'?"


def test_unknown_node_without_any_close_name(registry, tmp_path, empty_lib):
    path = write(tmp_path, '<root BTCPP_format="4"><BehaviorTree ID="T"><Action ID="Zzyzx"/></BehaviorTree></root>')
    assert error_of(registry, path, empty_lib) == (
        f"{path}:1: Zzyzx: unknown node 'Zzyzx' (objective behaviors lists the registered nodes)"
    )


def test_compact_tag_naming_a_tree_says_to_use_subtree(registry, tmp_path, empty_lib):
    path = write(tmp_path, """<root BTCPP_format="4" main_tree_to_execute="T">
  <BehaviorTree ID="T"><Helper/></BehaviorTree>
  <BehaviorTree ID="Helper"><AlwaysSuccess/></BehaviorTree>
</root>""")
    assert error_of(registry, path, empty_lib) == (
        f"{path}:2: Helper: unknown node 'Helper'; 'Helper' is a BehaviorTree: use <SubTree ID=\"Helper\"/>"
    )


def test_unknown_port(registry, tmp_path, empty_lib):
    path = write(tmp_path, """<root BTCPP_format="4">
  <BehaviorTree ID="T">
    <Typed x="1" y="2"/>
  </BehaviorTree>
</root>""")
    with pytest.raises(PortError) as info:
        load(registry, path, empty_lib)
    assert str(info.value) == f"{path}:3: Typed: unknown port 'y' (ports: flag, n, out, x)"


def test_missing_required_port(registry, tmp_path, empty_lib):
    path = write(tmp_path, """<root BTCPP_format="4">
  <BehaviorTree ID="T">

    <Typed n="2"/>
  </BehaviorTree>
</root>""")
    assert error_of(registry, path, empty_lib) == f"{path}:4: Typed: missing required port 'x'"


def test_bad_value(registry, tmp_path, empty_lib):
    path = write(tmp_path, """<root BTCPP_format="4">
  <BehaviorTree ID="T">
    <Sequence>
      <Typed x="fast"/>
    </Sequence>
  </BehaviorTree>
</root>""")
    assert error_of(registry, path, empty_lib) == f"{path}:4: Typed: port 'x' expects a number, got 'fast'"


def test_wrong_child_counts(registry, tmp_path, empty_lib):
    two = write(tmp_path, """<root BTCPP_format="4"><BehaviorTree ID="T">
  <Inverter>
    <AlwaysSuccess/>
    <AlwaysSuccess/>
  </Inverter>
</BehaviorTree></root>""", "two.xml")
    assert error_of(registry, two, empty_lib) == f"{two}:2: Inverter: a decorator takes exactly one child, got 2"
    leaf = write(tmp_path, """<root BTCPP_format="4"><BehaviorTree ID="T">
  <AlwaysSuccess><AlwaysFailure/></AlwaysSuccess>
</BehaviorTree></root>""", "leaf.xml")
    assert error_of(registry, leaf, empty_lib) == f"{leaf}:2: AlwaysSuccess: a Action is a leaf and takes no children, got 1"
    empty = write(tmp_path, """<root BTCPP_format="4"><BehaviorTree ID="T">
  <Sequence/>
</BehaviorTree></root>""", "empty.xml")
    assert error_of(registry, empty, empty_lib) == f"{empty}:2: Sequence: a Sequence needs at least one child, got none"
    roots = write(tmp_path, """<root BTCPP_format="4">
<BehaviorTree ID="T"><AlwaysSuccess/><AlwaysSuccess/></BehaviorTree></root>""", "roots.xml")
    assert error_of(registry, roots, empty_lib) == f"{roots}:2: T: a BehaviorTree has exactly one root node, got 2"


def test_explicit_tag_must_match_the_node_kind(registry, tmp_path, empty_lib):
    path = write(tmp_path, """<root BTCPP_format="4"><BehaviorTree ID="T">
  <Decorator ID="Sequence"><AlwaysSuccess/></Decorator>
</BehaviorTree></root>""")
    assert error_of(registry, path, empty_lib) == f"{path}:2: Sequence: 'Sequence' is a Control node, not a Decorator"


def test_unknown_underscore_attribute_is_refused_with_a_hint(registry, tmp_path, empty_lib):
    path = write(tmp_path, """<root BTCPP_format="4"><BehaviorTree ID="T">
  <AlwaysSuccess _skipif="true"/>
</BehaviorTree></root>""")
    assert error_of(registry, path, empty_lib) == (
        f"{path}:2: AlwaysSuccess: unknown attribute '_skipif'; did you mean '_skipIf'?"
    )


def test_btcpp_format_3_is_refused(registry, tmp_path, empty_lib):
    path = write(tmp_path, '<root BTCPP_format="3"><BehaviorTree ID="T"><AlwaysSuccess/></BehaviorTree></root>')
    assert error_of(registry, path, empty_lib) == (
        f"{path}:1: BTCPP_format=\"3\" is not supported: this runtime reads BehaviorTree.CPP v4 XML"
    )


def test_malformed_xml_reports_the_line(registry, tmp_path, empty_lib):
    path = write(tmp_path, '<root BTCPP_format="4">\n<BehaviorTree ID="T">\n<AlwaysSuccess>\n</BehaviorTree></root>')
    message = error_of(registry, path, empty_lib)
    assert message.startswith(f"{path}:4: not well-formed XML: ")


def test_condition_attributes_are_compiled_and_applied(registry, tmp_path, empty_lib):
    path = write(tmp_path, """<root BTCPP_format="4"><BehaviorTree ID="T">
  <Sequence>
    <Script code="x := 1"/>
    <AlwaysFailure _skipIf="x == 1"/>
    <Typed x="2" out="{y}" _onSuccess="done := true"/>
  </Sequence>
</BehaviorTree></root>""")
    tree = load(registry, path, empty_lib)
    assert run_to_end(tree) is Status.SUCCESS
    assert tree.blackboard.get("done") is True
    bad = write(tmp_path, """<root BTCPP_format="4"><BehaviorTree ID="T">
  <AlwaysSuccess _skipIf="x =="/>
</BehaviorTree></root>""", "bad.xml")
    assert error_of(registry, bad, empty_lib).startswith(f"{bad}:2: AlwaysSuccess")


# -- safe parsing ------------------------------------------------------------------------------
DOCTYPE_REFUSED = "DOCTYPE and entity declarations are not allowed in Objectives (refused for safety; remove the <!DOCTYPE ...> block)"


def test_doctype_is_refused(registry, tmp_path, empty_lib):
    path = write(tmp_path, """<?xml version="1.0"?>
<!DOCTYPE root>
<root BTCPP_format="4"><BehaviorTree ID="T"><AlwaysSuccess/></BehaviorTree></root>""")
    assert error_of(registry, path, empty_lib) == f"{path}:2: {DOCTYPE_REFUSED}"


def test_billion_laughs_is_refused_without_expanding(registry, tmp_path, empty_lib):
    lol = ['<!ENTITY lol "lol">'] + [f'<!ENTITY lol{i} "{("&lol" + (str(i - 1) if i > 1 else "") + ";") * 10}">' for i in range(1, 10)]
    path = write(tmp_path, "<?xml version=\"1.0\"?>\n<!DOCTYPE root [\n" + "\n".join(lol) + """
]>
<root BTCPP_format="4"><BehaviorTree ID="T"><LogMessage message="&lol9;"/></BehaviorTree></root>""")
    assert error_of(registry, path, empty_lib) == f"{path}:2: {DOCTYPE_REFUSED}"


def test_external_entity_file_read_is_refused(registry, tmp_path, empty_lib):
    secret = tmp_path / "secret.txt"
    secret.write_text("TOP-SECRET")
    path = write(tmp_path, f"""<?xml version="1.0"?>
<!DOCTYPE root [<!ENTITY xxe SYSTEM "file://{secret}">]>
<root BTCPP_format="4"><BehaviorTree ID="T"><LogMessage message="&xxe;"/></BehaviorTree></root>""")
    message = error_of(registry, path, empty_lib)
    assert message == f"{path}:2: {DOCTYPE_REFUSED}"
    assert "TOP-SECRET" not in message


def test_deep_nesting_is_refused(registry, tmp_path, empty_lib):
    depth = 210
    body = "<Inverter>" * depth + "<AlwaysSuccess/>" + "</Inverter>" * depth
    path = write(tmp_path, f'<root BTCPP_format="4"><BehaviorTree ID="T">{body}</BehaviorTree></root>')
    assert error_of(registry, path, empty_lib) == f"{path}:1: elements nest deeper than 200 levels"


def _subtree_chain(tmp_path: Path, subtrees: int) -> Path:
    trees = "".join(f'<BehaviorTree ID="T{i}"><SubTree ID="T{i + 1}"/></BehaviorTree>' for i in range(subtrees))
    return write(tmp_path, f'<root BTCPP_format="4" main_tree_to_execute="T0">{trees}<BehaviorTree ID="T{subtrees}"><AlwaysSuccess/></BehaviorTree></root>')


@pytest.mark.parametrize("subtrees", [150, 200, 500])
def test_a_subtree_chain_deeper_than_the_limit_is_refused_at_load(registry, tmp_path, empty_lib, subtrees):
    """A chain of SubTrees deeper than the limit is bad input at load (no RecursionError, no crash
    of the loader); the message names the outermost calls and the innermost one, the rest counted."""
    path = _subtree_chain(tmp_path, subtrees)
    assert error_of(registry, path, empty_lib) == (
        f"{path}:1: SubTree 'T1': {path}:1: SubTree 'T2': (147 more SubTree calls): {path}:1: SubTree 'T150': "
        f"{path}:1: {'AlwaysSuccess' if subtrees == 150 else 'SubTree'}: the tree nests more than 150 nodes deep after "
        "expanding SubTrees (151 trees deep: T0 -> T1 -> T2 -> ... -> T148 -> T149 -> T150)"
    )


def test_a_subtree_chain_at_the_limit_runs(registry, tmp_path, empty_lib):
    assert run_to_end(load(registry, _subtree_chain(tmp_path, 149), empty_lib)) is Status.SUCCESS


def test_huge_attribute_is_refused(registry, tmp_path, empty_lib):
    path = write(tmp_path, f'<root BTCPP_format="4"><BehaviorTree ID="T"><LogMessage message="{"a" * 70000}"/></BehaviorTree></root>')
    assert error_of(registry, path, empty_lib) == f"{path}:1: attribute 'message' is 70000 characters long (limit 65536)"


def test_exponential_subtree_expansion_is_bounded(registry, tmp_path, empty_lib):
    trees = ['<BehaviorTree ID="L0"><AlwaysSuccess/></BehaviorTree>']
    for i in range(1, 20):
        trees.append(f'<BehaviorTree ID="L{i}"><Sequence><SubTree ID="L{i-1}"/><SubTree ID="L{i-1}"/></Sequence></BehaviorTree>')
    path = write(tmp_path, f'<root BTCPP_format="4" main_tree_to_execute="L19">{"".join(trees)}</root>')
    assert "the tree has more than 20000 nodes after expanding SubTrees" in error_of(registry, path, empty_lib)


# -- SubTrees ----------------------------------------------------------------------------------
SUBTREE_XML = """<root BTCPP_format="4" main_tree_to_execute="Main">
  <BehaviorTree ID="Main">
    <Sequence>
      <Script code="a := 5; secret := 'parent'"/>
      <SubTree ID="Child" input="{a}" output="{result}" literal="7"/>
      <SubTree ID="Shared" _autoremap="true"/>
    </Sequence>
  </BehaviorTree>
  <BehaviorTree ID="Child">
    <Sequence>
      <Typed x="{input}" n="{literal}" out="{output}"/>
      <Script code="secret := 'child'; local := 1"/>
    </Sequence>
  </BehaviorTree>
  <BehaviorTree ID="Shared">
    <Script code="shared := a + 1"/>
  </BehaviorTree>
</root>"""


def test_subtree_remapping_literals_isolation_and_autoremap(registry, tmp_path, empty_lib):
    tree = load(registry, write(tmp_path, SUBTREE_XML), empty_lib)
    assert run_to_end(tree) is Status.SUCCESS
    board = dict(tree.blackboard.items())
    assert board["result"] == 35.0  # 5 * 7 written through the remapped 'output'
    assert board["secret"] == "parent"  # the child's 'secret' is its own
    assert "local" not in board
    assert board["shared"] == 6.0  # autoremap: reads and writes the caller's entries
    child = next(n.node for n in tree.nodes if isinstance(n.node, SubTree) and n.node.tree_id == "Child")
    assert child.remapping == {"input": "a", "output": "result"}
    assert child.literals == {"literal": "7"}
    assert dict(child.child_blackboard.items()) == {"literal": "7", "local": 1, "secret": "child"}


def test_subtree_model_defaults_and_unknown_ports(registry, tmp_path, empty_lib):
    path = write(tmp_path, """<root BTCPP_format="4" main_tree_to_execute="Main">
  <BehaviorTree ID="Main">
    <Sequence>
      <Script code="from_parent := 4"/>
      <SubTree ID="Child"/>
      <SubTree ID="Child" n="3" name="explicit"/>
    </Sequence>
  </BehaviorTree>
  <BehaviorTree ID="Child">
    <Typed x="{x}" n="{n}" out="{out}"/>
  </BehaviorTree>
  <TreeNodesModel>
    <SubTree ID="Child">
      <input_port name="x" default="{from_parent}"/>
      <input_port name="n" default="2" type="int"/>
      <output_port name="out" default="{product}"/>
    </SubTree>
  </TreeNodesModel>
</root>""")
    tree = load(registry, path, empty_lib)
    first, second = [n.node for n in tree.nodes if isinstance(n.node, SubTree)]
    assert first.remapping == {"x": "from_parent", "out": "product"} and first.literals == {"n": "2"}
    assert second.literals == {"n": "3"} and second.name == "explicit"
    assert run_to_end(tree) is Status.SUCCESS
    assert tree.blackboard.get("product") == 12.0

    bad = write(tmp_path, path.read_text().replace('n="3"', 'm="3"'), "bad.xml")
    assert error_of(registry, bad, empty_lib) == (
        f"{bad}:6: Child: unknown port 'm' (ports: n, out, x; model at {bad}:13)"
    )



def test_a_port_typo_suggests_the_port_meant(registry, tmp_path, empty_lib):
    """Node, SubTree, waypoint and service typos had a "did you mean"; port typos had none."""
    path = write(tmp_path, """<root BTCPP_format="4">
  <BehaviorTree ID="T">
    <Typed x="1" flagg="true"/>
  </BehaviorTree>
</root>""")
    assert error_of(registry, path, empty_lib) == f"{path}:3: Typed: unknown port 'flagg'; did you mean 'flag'? (ports: flag, n, out, x)"
    subtree = write(tmp_path, """<root BTCPP_format="4" main_tree_to_execute="T">
  <BehaviorTree ID="T"><SubTree ID="Child" nsteps="3"/></BehaviorTree>
  <BehaviorTree ID="Child"><AlwaysSuccess/></BehaviorTree>
  <TreeNodesModel><SubTree ID="Child"><input_port name="n_steps" default="2"/></SubTree></TreeNodesModel>
</root>""", "subtree.xml")
    assert error_of(registry, subtree, empty_lib) == (
        f"{subtree}:2: Child: unknown port 'nsteps'; did you mean 'n_steps'? (ports: n_steps; model at {subtree}:4)")


def test_model_default_fills_a_required_behavior_port(registry, tmp_path, empty_lib):
    path = write(tmp_path, """<root BTCPP_format="4">
  <BehaviorTree ID="T"><Typed out="{y}"/></BehaviorTree>
  <TreeNodesModel>
    <Action ID="Typed"><input_port name="x" default="1.5"/><input_port name="n" default="100"/></Action>
  </TreeNodesModel>
</root>""")
    tree = load(registry, path, empty_lib)
    assert run_to_end(tree) is Status.SUCCESS
    assert tree.blackboard.get("y") == 4.5  # x from the model; n keeps the class default 3
    bad = write(tmp_path, path.read_text().replace('default="1.5"', 'default="lots"'), "bad.xml")
    assert error_of(registry, bad, empty_lib) == (
        f"{bad}:4: Typed: TreeNodesModel default of port 'x' expects a number, got 'lots'"
    )


def test_undefined_subtree(registry, tmp_path, empty_lib):
    path = write(tmp_path, """<root BTCPP_format="4" main_tree_to_execute="Main">
  <BehaviorTree ID="Main">
    <SubTree ID="Pick Cube"/>
  </BehaviorTree>
  <BehaviorTree ID="Pick Cubes"><AlwaysSuccess/></BehaviorTree>
</root>""")
    assert error_of(registry, path, empty_lib) == (
        f"{path}:3: Pick Cube: undefined SubTree 'Pick Cube' (searched {path}, then {empty_lib}/*.xml); "
        "did you mean 'Pick Cubes'?"
    )


def test_recursive_subtrees_are_load_errors(registry, tmp_path, empty_lib):
    direct = write(tmp_path, """<root BTCPP_format="4" main_tree_to_execute="A">
  <BehaviorTree ID="A">
    <Sequence><AlwaysSuccess/><SubTree ID="A"/></Sequence>
  </BehaviorTree>
</root>""", "direct.xml")
    assert error_of(registry, direct, empty_lib) == f"{direct}:3: A: recursive SubTree: A -> A"
    indirect = write(tmp_path, """<root BTCPP_format="4" main_tree_to_execute="Main">
  <BehaviorTree ID="Main"><SubTree ID="A"/></BehaviorTree>
  <BehaviorTree ID="A"><SubTree ID="B"/></BehaviorTree>
  <BehaviorTree ID="B"><Fallback><AlwaysFailure/><SubTree ID="A"/></Fallback></BehaviorTree>
</root>""", "indirect.xml")
    assert error_of(registry, indirect, empty_lib) == (  # each SubTree call on the way is named, outermost first
        f"{indirect}:2: SubTree 'A': {indirect}:3: SubTree 'B': {indirect}:4: A: recursive SubTree: A -> B -> A")


def test_same_subtree_twice_is_not_recursion(registry, tmp_path, empty_lib):
    path = write(tmp_path, """<root BTCPP_format="4" main_tree_to_execute="Main">
  <BehaviorTree ID="Main"><Sequence><SubTree ID="A"/><SubTree ID="A"/></Sequence></BehaviorTree>
  <BehaviorTree ID="A"><AlwaysSuccess/></BehaviorTree>
</root>""")
    assert run_to_end(load(registry, path, empty_lib)) is Status.SUCCESS


def test_subtree_from_the_objectives_dir_and_search_paths(registry, tmp_path):
    objectives = tmp_path / "objectives"
    extra = tmp_path / "extra"
    objectives.mkdir()
    extra.mkdir()
    (objectives / "lib.xml").write_text("""<root BTCPP_format="4">
  <BehaviorTree ID="FromLibrary"><Script code="where := 'objectives'"/></BehaviorTree>
  <BehaviorTree ID="Overridden"><Script code="which := 'library'"/></BehaviorTree>
</root>""")
    (objectives / "broken.xml").write_text("<root>not closed")
    (extra / "more.xml").write_text("""<root BTCPP_format="4">
  <BehaviorTree ID="FromPath"><SubTree ID="Nested"/></BehaviorTree>
  <BehaviorTree ID="Nested"><Script code="nested := true"/></BehaviorTree>
  <BehaviorTree ID="FromLibrary"><Script code="where := 'extra'"/></BehaviorTree>
</root>""")
    main = write(tmp_path, """<root BTCPP_format="4" main_tree_to_execute="Main">
  <BehaviorTree ID="Main">
    <Sequence>
      <SubTree ID="FromLibrary" _autoremap="true"/>
      <SubTree ID="FromPath" _autoremap="true"/>
      <SubTree ID="Overridden" _autoremap="true"/>
    </Sequence>
  </BehaviorTree>
  <BehaviorTree ID="Overridden"><Script code="which := 'own'"/></BehaviorTree>
</root>""", "main.xml")
    tree = load_tree(main, registry, throwaway_context(), search_paths=[extra], objectives_dir=objectives)
    assert run_to_end(tree) is Status.SUCCESS
    board = dict(tree.blackboard.items())
    assert board["where"] == "objectives"  # objectives/ comes before --path
    assert board["which"] == "own"  # the file's own tree wins
    # Without the search path the SubTree is undefined, and the unreadable library file is named.
    with pytest.raises(LoadError) as info:
        load_tree(main, registry, throwaway_context(), objectives_dir=objectives)
    assert "undefined SubTree 'FromPath'" in str(info.value)
    assert "broken.xml" in str(info.value)


def test_two_library_files_defining_a_used_id_is_an_error(registry, tmp_path):
    lib = tmp_path / "lib"
    lib.mkdir()
    for name in ("one.xml", "two.xml"):
        (lib / name).write_text('<root BTCPP_format="4">\n<BehaviorTree ID="Dup"><AlwaysSuccess/></BehaviorTree></root>')
    (lib / "three.xml").write_text('<root BTCPP_format="4"><BehaviorTree ID="Fine"><AlwaysSuccess/></BehaviorTree></root>')
    uses_fine = write(tmp_path, '<root BTCPP_format="4"><BehaviorTree ID="M"><SubTree ID="Fine"/></BehaviorTree></root>', "a.xml")
    assert load(registry, uses_fine, lib).tree_id == "M"
    uses_dup = write(tmp_path, '<root BTCPP_format="4">\n<BehaviorTree ID="M"><SubTree ID="Dup"/></BehaviorTree></root>', "b.xml")
    assert error_of(registry, uses_dup, lib) == (
        f"{uses_dup}:2: Dup: SubTree 'Dup' is defined in several files: {lib}/one.xml:2 and {lib}/two.xml:2"
    )


def test_include_relative_to_the_file_and_refused_outside(registry, tmp_path, empty_lib):
    sub = tmp_path / "parts"
    sub.mkdir()
    (sub / "part.xml").write_text('<root BTCPP_format="4"><BehaviorTree ID="Part"><Script code="part := 1"/></BehaviorTree></root>')
    main = write(tmp_path, """<root BTCPP_format="4" main_tree_to_execute="M">
  <include path="parts/part.xml"/>
  <BehaviorTree ID="M"><SubTree ID="Part" _autoremap="true"/></BehaviorTree>
</root>""")
    tree = load(registry, main, empty_lib)
    assert run_to_end(tree) is Status.SUCCESS and tree.blackboard.get("part") == 1
    outside = write(sub, '<root BTCPP_format="4"><include path="../../x.xml"/><BehaviorTree ID="M"><AlwaysSuccess/></BehaviorTree></root>', "o.xml")
    message = error_of(registry, outside, empty_lib)
    assert message.startswith(f"{outside}:1: include '../../x.xml' is outside the allowed directories")


def test_shipped_fixture_loads(registry, empty_lib):
    tree = load(registry, DATA / "subtrees.xml", empty_lib)
    assert tree.tree_id == "Main"
    assert run_to_end(tree) is Status.SUCCESS
    assert tree.blackboard.get("greeting") == "hello world"


# -- validate ----------------------------------------------------------------------------------
def test_validate_checks_every_tree_of_a_library_file(registry, tmp_path, empty_lib):
    path = write(tmp_path, """<root BTCPP_format="4">
  <BehaviorTree ID="Good"><AlwaysSuccess/></BehaviorTree>
  <BehaviorTree ID="Bad"><Typed/></BehaviorTree>
</root>""")
    with pytest.raises(PortError) as info:
        validate(path, registry, objectives_dir=empty_lib).trees_or_raise()
    assert str(info.value) == f"{path}:3: Typed: missing required port 'x'"
    assert [t.tree_id for t in validate(path, registry, tree_id="Good", objectives_dir=empty_lib).trees] == ["Good"]


REMAPPED_TO_NOTHING = """<root BTCPP_format="4" main_tree_to_execute="Main">
  <BehaviorTree ID="Main"><SubTree ID="Child" x="{target}"/></BehaviorTree>
  <BehaviorTree ID="Child"><Typed x="{x}"/></BehaviorTree>
</root>"""
NOT_SHARED = """<root BTCPP_format="4" main_tree_to_execute="Main">
  <BehaviorTree ID="Main"><Sequence><Script code="x := 2"/><SubTree ID="Child"/></Sequence></BehaviorTree>
  <BehaviorTree ID="Child"><Typed x="{x}"/></BehaviorTree>
</root>"""
UNSET_READS = [
    (REMAPPED_TO_NOTHING, "port 'x' reads blackboard entry 'x', remapped to the caller's 'target', which is not set"),
    (NOT_SHARED, "port 'x' reads blackboard entry 'x', which is not set; a caller has 'x', but this SubTree's "
                 "blackboard is its own: pass it as a port (x=\"{x}\") or set _autoremap=\"true\" on the SubTree"),
]


@pytest.mark.parametrize("xml, reason", UNSET_READS, ids=["remapped-to-an-unset-entry", "no-autoremap"])
def test_a_subtree_reading_an_unset_entry_names_the_caller_s_key(registry, tmp_path, empty_lib, xml, reason):
    """It named the SubTree's key ('x', which the caller never wrote) and gave no _autoremap hint."""
    path = write(tmp_path, xml)
    tree = load(registry, path, empty_lib)
    with pytest.raises(PortError) as info:
        run_to_end(tree)
    assert str(info.value).endswith(f"{path}:3: Typed: {reason}"), str(info.value)


@pytest.mark.parametrize("xml, reason", UNSET_READS, ids=["remapped-to-an-unset-entry", "no-autoremap"])
def test_validate_finds_a_subtree_reading_an_entry_nothing_writes(registry, tmp_path, empty_lib, xml, reason):
    path = write(tmp_path, xml)
    errors = validate(path, registry, objectives_dir=empty_lib).errors
    assert [str(e) for e in errors] == [f"{path}:2: SubTree 'Child': {path}:3: Typed: {reason}"]
    fixed = (xml.replace('<SubTree ID="Child" x="{target}"/>', '<Sequence><Typed x="1" out="{target}"/><SubTree ID="Child" x="{target}"/></Sequence>')
             .replace('<SubTree ID="Child"/>', '<SubTree ID="Child" _autoremap="true"/>'))
    assert validate(write(tmp_path, fixed, "fixed.xml"), registry, objectives_dir=empty_lib).errors == []


def test_errors_in_an_included_file_name_that_file(registry, tmp_path, empty_lib):
    part = tmp_path / "part.xml"
    part.write_text('<root BTCPP_format="4">\n\n<BehaviorTree ID="Part"><Typed x="slow"/></BehaviorTree></root>')
    main = write(tmp_path, """<root BTCPP_format="4" main_tree_to_execute="M">
  <include path="part.xml"/>
  <BehaviorTree ID="M"><SubTree ID="Part"/></BehaviorTree>
</root>""")
    assert error_of(registry, main, empty_lib) == f"{main}:3: SubTree 'Part': {part}:3: Typed: port 'x' expects a number, got 'slow'"


def test_line_numbers_are_where_the_start_tag_begins(registry, tmp_path, empty_lib):
    path = write(tmp_path, """<root BTCPP_format="4">
  <!-- <Sequence> in a comment does not count -->
  <BehaviorTree ID="T">
    <Sequence>
      <AlwaysSuccess/><Typed
          x="1"
          n="many"/>
    </Sequence>
  </BehaviorTree>
</root>""")
    assert error_of(registry, path, empty_lib) == f"{path}:5: Typed: port 'n' expects an integer, got 'many'"


def test_a_loaded_tree_names_every_file_it_was_built_from(registry, tmp_path, empty_lib):
    """Its own file, its includes, and the library files of the SubTrees it uses (not the others)."""
    (tmp_path / "parts").mkdir()
    part = write(tmp_path / "parts", '<root BTCPP_format="4"><BehaviorTree ID="Part"><SubTree ID="Lib"/></BehaviorTree></root>',
                 "part.xml")
    used = write(empty_lib, '<root BTCPP_format="4"><BehaviorTree ID="Lib"><AlwaysSuccess/></BehaviorTree></root>', "lib.xml")
    write(empty_lib, '<root BTCPP_format="4"><BehaviorTree ID="Other"><AlwaysFailure/></BehaviorTree></root>', "other.xml")
    main = write(tmp_path, """<root BTCPP_format="4" main_tree_to_execute="M">
  <include path="parts/part.xml"/>
  <BehaviorTree ID="M"><SubTree ID="Part"/></BehaviorTree>
</root>""")
    assert load(registry, main, empty_lib).files == (main.resolve(), part.resolve(), used.resolve())
