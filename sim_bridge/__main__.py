"""``python -m sim_bridge MISSION.yaml ...``"""

from sim_bridge.cli import main

raise SystemExit(main())
