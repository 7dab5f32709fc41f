"""The engine: BehaviorTree.CPP v4 XML -> py_trees, ports, blackboard, clock, bus, runner.

The runtime imports neither ``behaviors`` nor ``sim``: both plug in through entry points
(groups ``objective.behaviors`` and ``objective.worlds``), found by the CLI.
"""
