"""The 2-D square of GWH14's first experiment (SPEC 3.1)."""
from ..domain import Domain

DOMAIN = Domain(__name__, example=dict(max_steps=12))
