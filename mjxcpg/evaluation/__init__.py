"""Evaluation of learned policies: the paper's protocols (``protocol``, ``rollout``,
``evaluate``), the transfer to the other engine and to the hardware robot (``transfer``), the
evaluation report and plots (``report``, ``plots``), every evaluation ``mjxcpg eval`` runs in
one list (``registry``) and rendering (``render``)."""
