"""The ecosystem's formats: QGroundControl ``.plan`` and GeoJSON, in and out of missions."""
