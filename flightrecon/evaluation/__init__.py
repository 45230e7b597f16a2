"""Evaluation: fixed viewpoints per scene, rendering and mesh metrics, tables and figures."""
