"""The application: the runner, the ``objective`` CLI, worlds, Groot2 monitoring, the Objective
server and its client, the protective stop, and building the interface packages.

May import every other room; no other room imports it (``tests/test_layers.py``)."""
