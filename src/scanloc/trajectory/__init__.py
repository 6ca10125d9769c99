"""Driven runs: routes planned through a map, a pure-pursuit drive with kidnaps, drifting
wheel odometry, and the on-disk run format (data/trajectories/<name>/) that the simulator,
the real-log reader and the report share. Localizers read runs; they never make them."""
