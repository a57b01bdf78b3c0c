"""`python -m courtloc.services.shooter_bridge [--config FILE]`: the shooter_bridge stage as this process."""
from __future__ import annotations

import sys

from courtloc.services.deployment import stage_main
from courtloc.services.shooter_bridge.service import ShooterBridgeService

if __name__ == "__main__":
    sys.exit(stage_main(ShooterBridgeService))
