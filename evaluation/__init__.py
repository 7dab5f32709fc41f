"""``objective eval``: run an Objective over many seeded episodes and report how often it works.

Modules, in the order an evaluation uses them:

- ``cli``: the command's arguments (``runtime.app.cli`` adds them) and its output;
- ``config``: ``EvalConfig``/``WorkerSpec`` and the identity that guards a resumed DIR;
- ``policies``: the policy specs, and the only import of the policy side (``policy``);
- ``worker``: ``EpisodeWorker``, which loads once and runs one episode per seed;
- ``executors`` (local processes) and ``ray_executor`` (Ray actors): where workers run;
- ``scheduler``: seeds to workers, records to ``episodes.jsonl``, retries, timeouts;
- ``store``: the DIR (``eval.json``, ``episodes.jsonl``, ``summary.json``);
- ``stats``: success rate, Wilson interval, failure groups, percentiles (pure);
- ``report``: ``report.html``; ``progress``: the terminal's progress bar.

See docs/evaluation.md.
"""
