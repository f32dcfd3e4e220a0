"""``python -m navformer_rl.cli ...``: the ``navformer`` command."""

import sys

from navformer_rl.cli.main import main

sys.exit(main())
