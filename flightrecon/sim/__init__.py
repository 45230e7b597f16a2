"""Simulation: MuJoCo world assembly, quadrotor plant, RGB-D camera, flight cycle and safety monitors."""
