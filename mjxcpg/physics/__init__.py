"""Physics: a robot's compiled model and what its sensors read (``model``), the engines that
step a batch of robots (``engines``: MuJoCo C, its batched rollout, MJX), and the perturbed
"hardware" robot (``hardware``).  Knows robots, not controllers."""
