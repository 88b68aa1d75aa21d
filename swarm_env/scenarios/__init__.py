"""Scenarios: the built-in YAML files, their loading and validation, and the random generator.

:mod:`~swarm_env.scenarios.loader` reads and checks scenario files (``load_scenario``, ``list_scenarios``);
:mod:`~swarm_env.scenarios.generator` draws ``random`` worlds. The ``*.yaml`` files here are the built-in
scenarios.
"""
