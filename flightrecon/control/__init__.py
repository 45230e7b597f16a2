"""Quadrotor control: trajectory interface, geometric SE(3) tracking controller, motor mixing."""
