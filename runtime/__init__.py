"""The engine: BehaviorTree.CPP v4 XML run by py_trees, in four rooms.

- ``runtime.tree``: the tree engine (loader, ports, blackboard, scripts, control nodes, registry);
- ``runtime.io``: bus, ROS 2 and clocks;
- ``runtime.motion``: robot model, planning scene and the motion vocabulary (``Samples``);
- ``runtime.app``: the runner, the CLI, worlds, Groot2, the Objective server;

and ``runtime.errors`` and ``runtime.extras``, which every room uses. ``io`` imports no other room,
``tree`` and ``motion`` only ``io``, and no room imports ``app`` (``tests/test_layers.py``).

The runtime imports nothing above it (``behaviors``, ``policy``, ``sim``; ``tests/test_layers.py``
checks): they plug in through entry points (groups ``objective.behaviors``, ``objective.worlds``,
``objective.default_world`` and ``objective.commands``), found by the CLI.
"""
