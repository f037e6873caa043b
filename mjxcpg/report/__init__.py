"""Every report and figure mjxcpg writes: a run's summary, Table 1 and learning figures
(``learning``), the evaluations' figures and sections (``evaluation``), the one report of a
run that holds them all (``document``) and every plot (``plots``)."""
