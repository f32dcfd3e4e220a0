"""``python -m navformer_rl.modules.decoding.native``: build (or find) the kernel and say whether it loads.

Exit status 0 and the library's path when it is available, 1 and the reason otherwise. Useful to build it
once before launching many workers, or to see why decoders take the torch path.
"""

from __future__ import annotations

import sys

from navformer_rl.modules.decoding.native.build import native_status


def main() -> int:
    status = native_status()
    if status.available:
        print(f"native transformer-step kernel: available ({status.reason})")
        return 0
    print(f"native transformer-step kernel: unavailable: {status.reason}", file=sys.stderr)
    return 1


if __name__ == "__main__":
    sys.exit(main())
