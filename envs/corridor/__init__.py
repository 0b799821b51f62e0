"""A 1-D corridor: the worked example of a domain (README "Adding a domain")."""
from ..domain import Domain

DOMAIN = Domain(__name__, example=dict(length=8, max_steps=12))
