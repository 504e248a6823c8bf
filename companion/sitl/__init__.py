"""The top layer's simulator wiring: the embedded stub launcher and the in-process Vehicle adapter.

These need both the companion app and sim_bridge, so they live above both (docs/design.md)."""
