"""Learning: the NGnet function approximator (``ngnet``), the stochastic policy (``policy``),
the continuous-time actor-critic (``actor_critic``) and one learner on one robot, its reward
and trial protocol (``learner``).  Pure JAX for one learner."""
