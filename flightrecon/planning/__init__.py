"""Planning: viewpoint library, occupancy map, distance field, OMPL paths, ruckig trajectories, feasibility."""
