"""Delayed GP Q-learning (Grande, Walsh & How, ICML 2014), batched over seeds."""
