"""The pure planning core: world, grid, A*, sparse optimisation, (B)DWA, local goals (fusion), the per-vehicle planner, headless runner.

No asyncio and no I/O in this package; it is tested without an event loop.
"""
