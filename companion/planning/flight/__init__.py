"""Flying a mission with its planners, above the core and the coordination: the fleet of planners
and schedule clocks, the headless runner, and the first vehicle's flown forecast."""
