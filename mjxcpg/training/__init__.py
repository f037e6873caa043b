"""Training: many learners in lockstep (``train``), configs (``config``), run directories and
checkpoints (``runs``), progress and TensorBoard events (``progress``, ``events``) and the
statistics of a run's results (``stats``)."""
