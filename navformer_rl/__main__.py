"""``python -m navformer_rl ...``: the ``navformer`` command (also under ``torchrun``)."""

import sys

from navformer_rl.cli.main import main

sys.exit(main())
