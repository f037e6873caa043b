"""Training: many learners in lockstep (``train``), configs (``config``), run directories and
checkpoints (``runs``), progress and TensorBoard events (``progress``, ``events``), a run's
report (``report``, ``plots``, ``stats``), the controls beside it (``controls``) and online
learning on the hardware robot (``online``)."""
