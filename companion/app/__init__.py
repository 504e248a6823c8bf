"""The asyncio mission runner: per-vehicle pilots, safety monitors, flight logs, embedded stub."""
