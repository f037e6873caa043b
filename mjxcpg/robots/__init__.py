"""Robot descriptions: one folder per robot, its MJCF beside a module of its names, home pose,
leg length and gait constants.  The bottom layer: it imports nothing else of mjxcpg."""
