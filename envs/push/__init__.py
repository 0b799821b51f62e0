"""Block pushing on a table in pybullet (SPEC 3.3), with a scripted pusher (``oracle``).
pybullet is imported when the first world is built, not with the domain."""
from ..domain import Domain

DOMAIN = Domain(__name__, baselines={"oracle": "baselines:OraclePusher"}, example=dict(max_steps=4, substeps=6))
