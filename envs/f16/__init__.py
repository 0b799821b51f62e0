"""GWH14's second experiment: holding the altitude of an unstable F-16 (SPEC 3.4)."""
from ..domain import Domain

DOMAIN = Domain(__name__, baselines={"lqr": "baselines:LQRPolicy", "pd": "baselines:PDPolicy"},
                example=dict(max_steps=12))
