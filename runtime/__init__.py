"""The engine: BehaviorTree.CPP v4 XML -> py_trees, ports, blackboard, clock, bus, runner.

The runtime imports nothing above it (``behaviors``, ``policy``, ``sim``; ``tests/test_layers.py``
checks): they plug in through entry points (groups ``objective.behaviors``, ``objective.worlds``,
``objective.default_world`` and ``objective.commands``), found by the CLI.
"""
