"""GWH14's second experiment: holding the altitude of an unstable F-16 (SPEC 3.4; issue 19).

Work in progress: the model (``dynamics.py``) and the env (``env.py``) are here and
tested; the domain is registered in ``envs.DOMAINS`` once its presets, its scripted
baselines (PD, LQR) and its analysis exist.
"""
