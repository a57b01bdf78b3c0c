"""`python -m courtloc.services.infer [--config FILE]`: the infer stage as this process."""
from __future__ import annotations

import sys

from courtloc.services.deployment import stage_main
from courtloc.services.infer.service import InferService

if __name__ == "__main__":
    sys.exit(stage_main(InferService))
