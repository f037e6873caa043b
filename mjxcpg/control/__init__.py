"""Control: the CPG (``cpg``), leg inverse kinematics (``ik``), reflexes and servo targets
(``controller``), a robot, its controller constants and an engine assembled (``sim``),
walking without learning and its gait measures (``walk``), and the sensor-only estimate of
height and velocity (``estimator``)."""
