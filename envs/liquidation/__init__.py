"""Optimal liquidation in the Almgren-Chriss market (SPEC 3.2), with its closed-form optimum."""
from ..domain import Domain

DOMAIN = Domain(__name__, baselines={"ac-optimal": "baselines:ACOptimalPolicy", "twap": "baselines:TWAPPolicy"},
                example=dict(trades=8, horizon=8))
