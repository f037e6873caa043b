"""Evaluation of learned policies: the paper's protocols (``protocol``, ``rollout``,
``evaluate``), the transfer to the other engine and to the hardware robot (``transfer``), the
controls beside Table 1 (``controls``), online learning on the hardware robot (``online``), every
evaluation ``mjxcpg eval`` runs in one list (``registry``) and rendering (``render``)."""
