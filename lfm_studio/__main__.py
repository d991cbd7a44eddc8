"""``python -m lfm_studio`` runs the ``lfm-studio`` command."""

import sys

from lfm_studio.cli import main

sys.exit(main())
