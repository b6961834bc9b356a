"""``python -m phri.study {study,report,questionnaire} ...``"""

from __future__ import annotations

import sys

from phri.study.cli import main

if __name__ == "__main__":
    sys.exit(main())
