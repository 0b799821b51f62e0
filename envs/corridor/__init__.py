"""A 1-D corridor: the worked example of a domain (docs/domains/corridor.md)."""
from ..domain import Domain

DOMAIN = Domain(__name__, example=dict(length=8, max_steps=12))
