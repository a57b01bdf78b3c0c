"""`python -m courtloc.services.camera [--config FILE]`: the camera stage as this process."""
from __future__ import annotations

import sys

from courtloc.services.camera.service import CameraService
from courtloc.services.deployment import stage_main

if __name__ == "__main__":
    sys.exit(stage_main(CameraService))
