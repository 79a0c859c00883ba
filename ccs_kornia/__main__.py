"""``python -m ccs_kornia ...``: see :mod:`ccs_kornia.cli`."""

from __future__ import annotations

import sys

from ccs_kornia.cli import main

if __name__ == "__main__":
    sys.exit(main())
