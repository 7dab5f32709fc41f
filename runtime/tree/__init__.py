"""The tree engine: BehaviorTree.CPP v4 XML loaded into py_trees, ports, blackboard, the control,
decorator and condition nodes, scripts, SubTrees and the node registry.

Imports ``runtime.errors``, ``runtime.extras`` and ``runtime.io`` (a node's context holds the clock
and the bus); nothing of ``runtime.motion`` or ``runtime.app`` (``tests/test_layers.py``)."""
