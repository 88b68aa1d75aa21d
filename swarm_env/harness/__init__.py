"""The harness around the simulation: what runs, scores and reports policies on the env.

``policies`` (the registry and the simple policies), ``episode`` (one seeded episode), ``evaluation``
(episodes and their aggregated metrics),
``recording`` (record and replay), ``leaderboard`` and ``paired`` (many policies on the same
episodes, paired statistics), ``bench`` (throughput), ``video`` and ``cli`` (``swarm-env``).

The dependency runs one way: the harness imports the simulation core (``swarm_env.env`` and the
modules below it), never the reverse (``tests/test_layout.py`` checks it).
"""
