"""Package discovery under installed names that differ from the repository's directories.

The repository keeps ``agents/`` and ``baselines/`` at its root, but installs them as
``swarm_env_agents`` and ``swarm_env_baselines``: ``agents`` is a name many projects use, and
``baselines`` is the import name of OpenAI Baselines, which many RL researchers still have
installed. ``pyproject.toml`` can map a package to a directory but cannot discover a mapped
package's subpackages, so they are found here; everything else is in ``pyproject.toml``.
"""

from setuptools import find_namespace_packages, setup

#: Installed import name -> directory in the repository.
PACKAGE_DIRS = {"swarm_env": "swarm_env", "swarm_env_agents": "agents", "swarm_env_baselines": "baselines"}


def _packages() -> list[str]:
    # Namespace discovery also lists the data folders (swarm_env/scenarios, baselines/checkpoints/<method>/s<k>),
    # so that their package-data files belong to a listed package, as setuptools asks.
    found = []
    for name, directory in PACKAGE_DIRS.items():
        found.append(name)
        found += [f"{name}.{sub}" for sub in find_namespace_packages(where=directory, exclude=["*__pycache__*"])]
    return found


setup(packages=_packages(), package_dir={k: v for k, v in PACKAGE_DIRS.items() if k != v})
