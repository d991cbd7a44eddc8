"""lfm_studio: a design studio for light-field microscopes.

The headless engine lives in :mod:`lfm_studio.engine`; the Qt studio in
:mod:`lfm_studio.ui` and :mod:`lfm_studio.widgets`.
"""

import os
import sys

__version__ = "0.1.0"

# Thread policy (lfm_studio.engine.threads): OpenMP threads sleep at barriers instead of
# spinning, so 2-thread torch runs do not collapse when another job holds a core. The
# runtime reads this once, when torch loads, so it is set here, before any torch import
# of ours; a value the user set wins.
WAIT_POLICY_AT_START = os.environ.get("OMP_WAIT_POLICY")  # the user's choice, if any
TORCH_LOADED_FIRST = "torch" in sys.modules  # then the runtime has read the policy already
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")
