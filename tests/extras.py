"""Why a test of an optional extra skips: said once, in the words a developer can act on."""

TORCH_MISSING = ("torch is not installed: the paper network's tests need the training extra "
                 "(CPU build: see README, Development; .ci/run installs it)")
