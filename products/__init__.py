"""``poseidon export``: a run for Foxglove (well-known schemas) or as a ROS 1 / ROS 2 bag."""
