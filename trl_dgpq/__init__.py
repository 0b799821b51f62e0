"""Delayed GP Q-learning (Grande, Walsh & How, ICML 2014), batched over seeds."""
from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("trl-dgpq")
except PackageNotFoundError:  # a checkout on sys.path that was never installed
    __version__ = "0.1.0+unknown"
