"""The pure planning core: world, grid, A*, sparse optimisation, (B)DWA, fusion, headless runner.

No asyncio and no I/O in this package; it is tested without an event loop.
"""
