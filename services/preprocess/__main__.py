"""`python -m courtloc.services.preprocess [--config FILE]`: the preprocess stage as this process."""
from __future__ import annotations

import sys

from courtloc.services.deployment import stage_main
from courtloc.services.preprocess.service import PreprocessService

if __name__ == "__main__":
    sys.exit(stage_main(PreprocessService))
