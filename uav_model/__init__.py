"""The shared model: frames, the mission schema and loader, the world and motion models, the plant.

The bottom layer. The planning core (companion.planning) and the stub (sim_bridge) both stand on it
and never import each other; this package imports no other project package (docs/design.md)."""
