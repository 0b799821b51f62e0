"""The package list, found rather than written: envs/ and collectors/ install as
trl_dgpq.envs and trl_dgpq.collectors, each with every subpackage (a domain folder
under envs/ is one). Everything else is in pyproject.toml."""
from setuptools import find_packages, setup

ROOTS = {"trl_dgpq": "trl_dgpq", "trl_dgpq.envs": "envs", "trl_dgpq.collectors": "collectors"}

setup(packages=[f"{name}.{sub}" if sub else name for name, folder in ROOTS.items()
                for sub in ["", *find_packages(folder)]],
      package_dir={name: folder for name, folder in ROOTS.items() if name != folder})
